//! The Delta log itself: the actions pointreggpt writes and reads (`protocol`, `metaData`, `add`,
//! `remove`, `commitInfo`), a commit file as JSON lines, its name (`<version:020>.json`), and the replay
//! of the commits into the table's state (the active files, the protocol and the metadata).
//!
//! Pure: no I/O here. Actions other than these (`txn`, `cdc`, `domainMetadata`, ...) are skipped on
//! replay; a commit line that is not a JSON object with one action is refused naming the file and line.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::path::Path;

/// The reader and writer versions pointreggpt's tables need (no table features): any Delta reader reads them.
pub const MIN_READER_VERSION: u32 = 1;
pub const MIN_WRITER_VERSION: u32 = 2;

/// Tag of an add action holding the shard index (a Delta tag value is a string).
pub const SHARD_TAG: &str = "shard";
/// Tag of an add action holding the blake3 of the shard file (from its manifest entry).
pub const BLAKE3_TAG: &str = "blake3";

/// `protocol`: the reader and writer versions a client needs.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct Protocol {
    pub min_reader_version: u32,
    pub min_writer_version: u32,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reader_features: Option<Vec<String>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub writer_features: Option<Vec<String>>,
}

/// `metaData.format`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Format {
    pub provider: String,
    #[serde(default)]
    pub options: BTreeMap<String, String>,
}

/// `metaData`: the table's id, schema and settings.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct Metadata {
    pub id: String,
    #[serde(default)]
    pub name: Option<String>,
    #[serde(default)]
    pub description: Option<String>,
    pub format: Format,
    pub schema_string: String,
    #[serde(default)]
    pub partition_columns: Vec<String>,
    #[serde(default)]
    pub configuration: BTreeMap<String, String>,
    #[serde(default)]
    pub created_time: Option<i64>,
}

/// `add`: a data file joins the table.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct Add {
    /// Relative to the table root (`shards/pairs-000042.parquet`).
    pub path: String,
    #[serde(default)]
    pub partition_values: BTreeMap<String, Option<String>>,
    pub size: u64,
    /// Milliseconds since the Unix epoch.
    pub modification_time: i64,
    pub data_change: bool,
    /// JSON text: `{"numRecords": n}`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stats: Option<String>,
    #[serde(default)]
    pub tags: BTreeMap<String, String>,
}

/// `remove`: a data file leaves the table (it stays readable by older versions while it exists).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct Remove {
    pub path: String,
    /// Milliseconds since the Unix epoch.
    #[serde(default)]
    pub deletion_timestamp: Option<i64>,
    pub data_change: bool,
    #[serde(default)]
    pub extended_file_metadata: Option<bool>,
    #[serde(default)]
    pub partition_values: Option<BTreeMap<String, Option<String>>>,
    #[serde(default)]
    pub size: Option<u64>,
    #[serde(default)]
    pub tags: Option<BTreeMap<String, String>>,
}

impl Remove {
    /// The remove of the active file `add`, at `now_ms`.
    pub fn of(add: &Add, now_ms: i64) -> Remove {
        Remove {
            path: add.path.clone(),
            deletion_timestamp: Some(now_ms),
            data_change: true,
            extended_file_metadata: Some(true),
            partition_values: Some(add.partition_values.clone()),
            size: Some(add.size),
            tags: Some(add.tags.clone()),
        }
    }
}

/// One line of a commit.
#[derive(Clone, Debug, PartialEq)]
pub enum Action {
    Protocol(Protocol),
    Metadata(Metadata),
    Add(Add),
    Remove(Remove),
    /// `commitInfo`, free-form.
    CommitInfo(Value),
    /// An action this code does not interpret (kept by name only).
    Other(String),
}

impl Action {
    /// The action as one JSON line (`{"add": {...}}`).
    pub fn to_json(&self) -> Value {
        let value = |v: Result<Value, serde_json::Error>| v.expect("a Delta action serializes");
        match self {
            Action::Protocol(p) => json!({ "protocol": value(serde_json::to_value(p)) }),
            Action::Metadata(m) => json!({ "metaData": value(serde_json::to_value(m)) }),
            Action::Add(a) => json!({ "add": value(serde_json::to_value(a)) }),
            Action::Remove(r) => json!({ "remove": value(serde_json::to_value(r)) }),
            Action::CommitInfo(v) => json!({ "commitInfo": v }),
            Action::Other(name) => Value::Object(serde_json::Map::from_iter([(name.clone(), json!({}))])),
        }
    }
}

/// The name of the commit file of `version` in `_delta_log/`.
pub fn commit_name(version: u64) -> String {
    format!("{version:020}.json")
}

/// The version of a commit file name (`00000000000000000003.json`), `None` for other files
/// (checkpoints, `_last_checkpoint`, `.crc`, temporary files).
pub fn parse_commit_name(name: &str) -> Option<u64> {
    let digits = name.strip_suffix(".json")?;
    (digits.len() == 20 && digits.bytes().all(|b| b.is_ascii_digit())).then(|| digits.parse().ok()).flatten()
}

/// The text of a commit: one JSON action a line, each line ending with a newline.
pub fn commit_text(actions: &[Action]) -> String {
    actions.iter().map(|a| a.to_json().to_string() + "\n").collect()
}

/// Parses the commit `text` read from `location` (for messages).
pub fn parse_commit(text: &str, location: &Path) -> Result<Vec<Action>> {
    let mut actions = Vec::new();
    for (i, line) in text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty()) {
        let bad = |m: String| Error::input(location, format!("line {}: {m}", i + 1));
        let value: Value = serde_json::from_str(line).map_err(|e| bad(format!("not JSON: {e}")))?;
        let Some((name, body)) = value.as_object().filter(|o| o.len() == 1).and_then(|o| o.iter().next()) else {
            return Err(bad("not a Delta action (a JSON object with one key)".into()));
        };
        let parse = |what: &str| bad(format!("not a valid `{what}` action"));
        actions.push(match name.as_str() {
            "protocol" => Action::Protocol(serde_json::from_value(body.clone()).map_err(|_| parse(name))?),
            "metaData" => Action::Metadata(serde_json::from_value(body.clone()).map_err(|_| parse(name))?),
            "add" => Action::Add(serde_json::from_value(body.clone()).map_err(|_| parse(name))?),
            "remove" => Action::Remove(serde_json::from_value(body.clone()).map_err(|_| parse(name))?),
            "commitInfo" => Action::CommitInfo(body.clone()),
            other => Action::Other(other.to_string()),
        });
    }
    Ok(actions)
}

/// The table as of a version: what replaying the commits `0..=version` gives.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TableState {
    /// The last version replayed, `None` before version 0 (no log yet).
    pub version: Option<u64>,
    pub protocol: Option<Protocol>,
    pub metadata: Option<Metadata>,
    /// The active files by path.
    pub files: BTreeMap<String, Add>,
}

impl TableState {
    /// The version the next commit must have.
    pub fn next_version(&self) -> u64 {
        self.version.map_or(0, |v| v + 1)
    }

    /// Replays the commit `version` (the next one) read from `location`.
    pub fn apply(&mut self, version: u64, actions: Vec<Action>, location: &Path) -> Result<()> {
        if version != self.next_version() {
            return Err(Error::input(
                location,
                format!("commit {version} does not follow version {:?}: the log has a gap (or starts at a checkpoint another engine wrote)", self.version),
            ));
        }
        for action in actions {
            match action {
                Action::Protocol(p) => self.protocol = Some(p),
                Action::Metadata(m) => self.metadata = Some(m),
                Action::Add(a) => {
                    self.files.insert(a.path.clone(), a);
                }
                Action::Remove(r) => {
                    self.files.remove(&r.path);
                }
                Action::CommitInfo(_) | Action::Other(_) => {}
            }
        }
        if self.protocol.is_none() || self.metadata.is_none() {
            return Err(Error::input(location, "the log has no `protocol` or no `metaData` action by this version"));
        }
        self.version = Some(version);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn add(path: &str, size: u64) -> Add {
        Add {
            path: path.into(),
            partition_values: BTreeMap::new(),
            size,
            modification_time: 1_700_000_000_000,
            data_change: true,
            stats: Some(r#"{"numRecords":3}"#.into()),
            tags: BTreeMap::from([(SHARD_TAG.into(), "1".into())]),
        }
    }

    fn head() -> Vec<Action> {
        let protocol = Protocol { min_reader_version: 1, min_writer_version: 2, reader_features: None, writer_features: None };
        let metadata = Metadata {
            id: "00000000-0000-0000-0000-000000000000".into(),
            name: Some("pairs".into()),
            description: None,
            format: Format { provider: "parquet".into(), options: BTreeMap::new() },
            schema_string: r#"{"type":"struct","fields":[]}"#.into(),
            partition_columns: vec![],
            configuration: BTreeMap::new(),
            created_time: Some(0),
        };
        vec![Action::CommitInfo(json!({"timestamp": 1})), Action::Protocol(protocol), Action::Metadata(metadata)]
    }

    #[test]
    fn commits_round_trip_in_the_protocol_spelling() {
        let mut actions = head();
        actions.push(Action::Add(add("shards/pairs-000001.parquet", 10)));
        actions.push(Action::Remove(Remove::of(&add("shards/pairs-000002.parquet", 20), 5)));
        let text = commit_text(&actions);
        assert_eq!(text.lines().count(), 5);
        assert!(text.contains(r#""minReaderVersion":1"#) && text.contains(r#""schemaString""#) && text.contains(r#""modificationTime""#));
        assert!(text.contains(r#""dataChange":true"#) && text.contains(r#""deletionTimestamp":5"#) && text.contains(r#""partitionValues":{}"#));
        assert_eq!(parse_commit(&text, Path::new("c.json")).unwrap(), actions);
        assert_eq!(commit_name(3), "00000000000000000003.json");
        assert_eq!(parse_commit_name(&commit_name(1234)), Some(1234));
        for other in ["_last_checkpoint", "00000000000000000010.checkpoint.parquet", "0001.json", "00000000000000000003.crc"] {
            assert_eq!(parse_commit_name(other), None, "{other}");
        }
    }

    #[test]
    fn replay_adds_removes_and_re_adds() {
        let mut state = TableState::default();
        let mut v0 = head();
        v0.extend([Action::Add(add("a", 1)), Action::Add(add("b", 2)), Action::Other("txn".into())]);
        state.apply(0, v0, Path::new("0")).unwrap();
        state.apply(1, vec![Action::Remove(Remove::of(&add("a", 1), 9))], Path::new("1")).unwrap();
        assert_eq!(state.files.keys().collect::<Vec<_>>(), ["b"]);
        state.apply(2, vec![Action::Add(add("a", 7)), Action::Add(add("b", 8))], Path::new("2")).unwrap();
        assert_eq!((state.files["a"].size, state.files["b"].size, state.version), (7, 8, Some(2)));
        let err = state.apply(4, vec![], Path::new("/t/_delta_log/4.json")).unwrap_err().to_string();
        assert!(err.contains("/t/_delta_log/4.json") && err.contains("gap"), "{err}");
        let err = TableState::default().apply(0, vec![Action::Add(add("a", 1))], Path::new("0.json")).unwrap_err().to_string();
        assert!(err.contains("protocol"), "{err}");
    }

    #[test]
    fn bad_lines_are_refused_naming_file_and_line() {
        for (text, want) in [("{\"add\": {}}\n", "line 1: not a valid `add`"), ("\n[1]\n", "line 2: not a Delta action"), ("{\n", "line 1: not JSON")] {
            let err = parse_commit(text, Path::new("/d/_delta_log/00000000000000000000.json")).unwrap_err().to_string();
            assert!(err.contains("00000000000000000000.json") && err.contains(want), "{err}");
        }
    }
}
