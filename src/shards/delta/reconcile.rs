//! What a publish commits, as pure functions: the table a dataset should be (its `protocol` and
//! `metaData`, one `add` per committed `pairs` shard) and the actions that take the log's current state
//! there (adds for shards it lacks or holds with other bytes, removes for files no manifest entry names).

use super::log::{Action, Add, Format, Metadata, Protocol, Remove, TableState, BLAKE3_TAG, MIN_READER_VERSION, MIN_WRITER_VERSION, SHARD_TAG};
use crate::error::{Error, Result};
use crate::shards::dataset::{DatasetHeader, SHARDS_DIR};
use crate::shards::manifest::{parse_rfc3339, ManifestEntry};
use std::collections::BTreeMap;
use std::path::Path;

/// The protocol of every table pointreggpt writes.
pub fn protocol() -> Protocol {
    Protocol { min_reader_version: MIN_READER_VERSION, min_writer_version: MIN_WRITER_VERSION, reader_features: None, writer_features: None }
}

/// The `metaData` of a dataset's table: an id derived from the dataset (its config hash and creation
/// time, so a log rebuilt from the manifest is the same table), the schema, no partitions.
pub fn metadata(header: &DatasetHeader, schema_string: String) -> Metadata {
    let h = blake3::hash(format!("{}~{}", header.config_hash, header.created).as_bytes()).to_hex();
    let id = format!("{}-{}-{}-{}-{}", &h[0..8], &h[8..12], &h[12..16], &h[16..20], &h[20..32]);
    Metadata {
        id,
        name: Some(crate::shards::PAIRS_TABLE.to_string()),
        description: Some(format!(
            "pointreggpt pairs ({}), config {}; a view of the dataset's manifest kept by `pointreggpt publish`",
            header.schema_version, header.config_hash
        )),
        format: Format { provider: "parquet".into(), options: BTreeMap::new() },
        schema_string,
        partition_columns: vec![],
        configuration: BTreeMap::new(),
        created_time: parse_rfc3339(&header.created).map(|s| s as i64 * 1000),
    }
}

/// Refuses a log this publisher may not extend: a newer protocol, or another table (other id or schema).
pub fn check_table(state: &TableState, expected: &Metadata, log_dir: &Path) -> Result<()> {
    let rebuild = "delete the _delta_log/ folder to rebuild the table from the manifest (its history is lost)";
    if let Some(p) = &state.protocol {
        if p.min_reader_version > MIN_READER_VERSION || p.min_writer_version > MIN_WRITER_VERSION || p.writer_features.is_some() {
            return Err(Error::input(
                log_dir,
                format!(
                    "the table needs Delta reader {} / writer {}{}: newer than this publisher writes ({MIN_READER_VERSION} / {MIN_WRITER_VERSION}); {rebuild}",
                    p.min_reader_version,
                    p.min_writer_version,
                    p.writer_features.as_ref().map(|f| format!(" with features {f:?}")).unwrap_or_default()
                ),
            ));
        }
    }
    if let Some(m) = &state.metadata {
        if m.id != expected.id || m.schema_string != expected.schema_string || !m.partition_columns.is_empty() {
            let what = if m.id != expected.id { "another table id (another dataset's log?)" } else { "another schema or partitioning" };
            return Err(Error::input(log_dir, format!("the Delta log describes {what} than this dataset; {rebuild}")));
        }
    }
    Ok(())
}

/// The `add` action of a committed shard: its file relative to the table root, size, the commit time
/// of its manifest entry, its row count as stats, and its shard index and blake3 as tags.
pub fn shard_add(entry: &ManifestEntry) -> Add {
    Add {
        path: format!("{SHARDS_DIR}/{}", entry.file),
        partition_values: BTreeMap::new(),
        size: entry.bytes,
        modification_time: parse_rfc3339(&entry.created).map_or(0, |s| s as i64 * 1000),
        data_change: true,
        stats: Some(serde_json::json!({ "numRecords": entry.rows }).to_string()),
        tags: BTreeMap::from([(SHARD_TAG.to_string(), entry.shard.to_string()), (BLAKE3_TAG.to_string(), entry.blake3.clone())]),
    }
}

/// Whether the active file `active` is the shard file `wanted` describes (same path, size and blake3).
fn same_file(active: &Add, wanted: &Add) -> bool {
    active.path == wanted.path && active.size == wanted.size && active.tags.get(BLAKE3_TAG) == wanted.tags.get(BLAKE3_TAG)
}

/// The actions that make `state` hold exactly the committed shards `entries`: a remove for every active
/// file that is not a committed shard file, an add for every committed shard the table lacks or holds
/// with other bytes (an add replaces the active file of the same path: no remove for it). Empty when the
/// table is current. Removes come first, each list by path.
pub fn plan(state: &TableState, entries: &BTreeMap<u64, ManifestEntry>, now_ms: i64) -> Vec<Action> {
    let wanted: BTreeMap<String, Add> = entries.values().map(shard_add).map(|a| (a.path.clone(), a)).collect();
    let removes = state.files.values().filter(|a| !wanted.contains_key(&a.path)).map(|a| Action::Remove(Remove::of(a, now_ms)));
    let adds = wanted.values().filter(|w| !state.files.get(&w.path).is_some_and(|a| same_file(a, w))).map(|w| Action::Add(w.clone()));
    removes.chain(adds).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shards::manifest::utc_now;
    use crate::shards::schema::SCHEMA_VERSION;

    fn entry(shard: u64, blake3: &str) -> ManifestEntry {
        ManifestEntry {
            table: "pairs".into(),
            shard,
            first_unit: shard * 2,
            units: 2,
            rows: 2,
            rows_by_status: BTreeMap::from([("ok".into(), 2)]),
            file: format!("pairs-{shard:06}.parquet"),
            bytes: 100 + shard,
            blake3: blake3.into(),
            schema_version: SCHEMA_VERSION.into(),
            config_hash: "h".into(),
            code_version: "t".into(),
            worker: "w".into(),
            created: "2025-01-31T12:00:00Z".into(),
        }
    }

    fn header() -> DatasetHeader {
        DatasetHeader { config_hash: "h".into(), schema_version: SCHEMA_VERSION.into(), code_version: "t".into(), created: utc_now() }
    }

    /// `state` after committing `actions` as its next version.
    fn applied(mut state: TableState, actions: Vec<Action>) -> TableState {
        let mut all = vec![Action::Protocol(protocol()), Action::Metadata(metadata(&header(), "{}".into()))];
        all.extend(actions);
        let v = state.next_version();
        state.apply(v, all, Path::new("x")).unwrap();
        state
    }

    #[test]
    fn adds_what_is_missing_once_and_removes_what_was_withdrawn() {
        let entries: BTreeMap<u64, ManifestEntry> = (0..3).map(|s| (s, entry(s, "aa"))).collect();
        let first = plan(&TableState::default(), &entries, 7);
        assert_eq!(first.len(), 3);
        let Action::Add(a) = &first[0] else { panic!("{first:?}") };
        assert_eq!((a.path.as_str(), a.size, a.modification_time), ("shards/pairs-000000.parquet", 100, 1_738_324_800_000));
        assert_eq!((a.tags[SHARD_TAG].as_str(), a.stats.as_deref()), ("0", Some(r#"{"numRecords":2}"#)));
        let state = applied(TableState::default(), first);
        assert!(plan(&state, &entries, 7).is_empty(), "publishing twice adds nothing");
        // Shard 1 withdrawn, shard 2 rebuilt with other bytes, shard 5 committed.
        let mut now = entries.clone();
        now.remove(&1);
        now.insert(2, entry(2, "bb"));
        now.insert(5, entry(5, "cc"));
        let next = plan(&state, &now, 9);
        let paths: Vec<(bool, &str)> = next
            .iter()
            .map(|a| match a {
                Action::Add(a) => (true, a.path.as_str()),
                Action::Remove(r) => (false, r.path.as_str()),
                other => panic!("{other:?}"),
            })
            .collect();
        assert_eq!(paths, [(false, "shards/pairs-000001.parquet"), (true, "shards/pairs-000002.parquet"), (true, "shards/pairs-000005.parquet")]);
        let Action::Remove(r) = &next[0] else { unreachable!() };
        assert_eq!((r.deletion_timestamp, r.size, r.tags.as_ref().unwrap()[SHARD_TAG].as_str()), (Some(9), Some(101), "1"));
        let state = applied(state, next);
        assert!(plan(&state, &now, 9).is_empty());
        assert_eq!(state.files["shards/pairs-000002.parquet"].tags[BLAKE3_TAG], "bb");
    }

    #[test]
    fn another_table_or_a_newer_protocol_is_refused() {
        let ours = metadata(&header(), "{\"s\":1}".into());
        assert_eq!(ours.id, metadata(&header(), "x".into()).id, "the id follows the dataset, not the call");
        assert_eq!(ours.id.len(), 36);
        let mut state = TableState { protocol: Some(protocol()), metadata: Some(ours.clone()), ..Default::default() };
        check_table(&state, &ours, Path::new("/d/_delta_log")).unwrap();
        let other = Metadata { schema_string: "{}".into(), ..ours.clone() };
        let err = check_table(&state, &other, Path::new("/d/_delta_log")).unwrap_err().to_string();
        assert!(err.contains("/d/_delta_log") && err.contains("schema") && err.contains("rebuild"), "{err}");
        state.protocol = Some(Protocol { min_writer_version: 7, writer_features: Some(vec!["deletionVectors".into()]), ..protocol() });
        let err = check_table(&state, &ours, Path::new("/d/_delta_log")).unwrap_err().to_string();
        assert!(err.contains("writer 7") && err.contains("deletionVectors"), "{err}");
    }
}
