//! Manifest entries: one small JSON file per committed shard (`manifest/<table>-<shard:06>.json`).
//!
//! A shard exists for readers and for resume only when its entry exists; the entry records what the
//! shard file must be (size, blake3) so that `verify` can prove it.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;
use std::time::{SystemTime, UNIX_EPOCH};

/// What a committed shard is (`schemas/pairs-v1.md`, "Manifest entry").
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ManifestEntry {
    /// Table name (`pairs`, `labels`).
    pub table: String,
    /// Shard index.
    pub shard: u64,
    /// The shard holds work units `first_unit .. first_unit + units`.
    pub first_unit: u64,
    pub units: u64,
    /// Rows in the shard file.
    pub rows: u64,
    /// Rows per status.
    pub rows_by_status: BTreeMap<String, u64>,
    /// File name in `shards/`: `<table>-<shard:06>.parquet` in a folder, `<table>-<shard:06>-<id>.parquet`
    /// (an immutable object under a unique name) on an object store.
    pub file: String,
    /// Size of the file.
    pub bytes: u64,
    /// blake3 of the file's bytes, hex.
    pub blake3: String,
    /// The table's schema version (from the batch's schema metadata; empty if it had none).
    pub schema_version: String,
    /// The dataset's config hash.
    pub config_hash: String,
    /// `pointreggpt <version>` that committed the shard.
    pub code_version: String,
    /// Who committed it.
    pub worker: String,
    /// UTC time of the commit, RFC 3339.
    pub created: String,
}

/// `<table>-<shard:06>`, the stem of a shard's file and of its manifest entry.
pub fn shard_stem(table: &str, shard: u64) -> String {
    format!("{table}-{shard:06}")
}

/// Parses `<table>-<digits>.<ext>` into (table, shard).
pub fn parse_shard_file_name<'a>(name: &'a str, ext: &str) -> Option<(&'a str, u64)> {
    let stem = name.strip_suffix(ext)?.strip_suffix('.')?;
    let (table, shard) = stem.rsplit_once('-')?;
    if shard.len() < 6 || !shard.bytes().all(|b| b.is_ascii_digit()) || check_table_name(table).is_err() {
        return None;
    }
    Some((table, shard.parse().ok()?))
}

/// Parses a shard object's name `<table>-<digits>-<id>.parquet` (id: lowercase hex or letters and
/// digits) into (table, shard, id).
pub fn parse_object_file_name(name: &str) -> Option<(&str, u64, &str)> {
    let stem = name.strip_suffix(".parquet")?;
    let (table, rest) = stem.split_once('-')?;
    let (shard, id) = rest.split_once('-')?;
    let id_ok = !id.is_empty() && id.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit());
    if shard.len() < 6 || !shard.bytes().all(|b| b.is_ascii_digit()) || !id_ok || check_table_name(table).is_err() {
        return None;
    }
    Some((table, shard.parse().ok()?, id))
}

/// Table names are `[a-z0-9_]+` (they become file names and are split at the last `-`).
pub fn check_table_name(table: &str) -> Result<()> {
    if !table.is_empty() && table.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_') {
        Ok(())
    } else {
        Err(Error::InvalidArgument(format!("table name {table:?}: use lowercase letters, digits and `_`")))
    }
}

impl ManifestEntry {
    /// The JSON text of the entry (pretty, one key a line, ending with a newline).
    pub fn to_json(&self) -> String {
        let mut s = serde_json::to_string_pretty(self).expect("a manifest entry serializes");
        s.push('\n');
        s
    }

    /// Reads and checks the entry at `path` (named `<table>-<shard:06>.json`): it must parse and agree
    /// with its file name.
    pub fn read(path: &Path) -> Result<ManifestEntry> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or_default();
        ManifestEntry::parse(&text, name, path)
    }

    /// Parses and checks the text of the entry named `name` (at `location`, for messages): it must
    /// agree with its name, and name a shard file of its own shard.
    pub fn parse(text: &str, name: &str, location: &Path) -> Result<ManifestEntry> {
        let entry: ManifestEntry =
            serde_json::from_str(text).map_err(|e| Error::input(location, format!("not a manifest entry: {e}")))?;
        let stem = shard_stem(&entry.table, entry.shard);
        let expected = format!("{stem}.json");
        if name != expected {
            return Err(Error::input(location, format!("entry is for {expected}, not {name}")));
        }
        let own_object = parse_object_file_name(&entry.file).is_some_and(|(t, s, _)| t == entry.table && s == entry.shard);
        if entry.file != format!("{stem}.parquet") && !own_object {
            return Err(Error::input(location, format!("entry names an unexpected shard file {:?}", entry.file)));
        }
        if entry.rows_by_status.values().sum::<u64>() != entry.rows {
            return Err(Error::input(location, "rows_by_status does not add up to rows"));
        }
        Ok(entry)
    }
}

/// The current UTC time, RFC 3339 with seconds (`2025-01-31T12:00:00Z`).
pub fn utc_now() -> String {
    let secs = SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
    rfc3339(secs)
}

/// Parses the RFC 3339 UTC times [`utc_now`] writes (`2025-01-31T12:00:00Z`) into seconds since the Unix
/// epoch; `None` for any other form.
pub fn parse_rfc3339(text: &str) -> Option<u64> {
    let b = text.as_bytes();
    let shape_ok = b.len() == 20
        && b.iter().enumerate().all(|(i, c)| match i {
            4 | 7 => *c == b'-',
            10 => *c == b'T',
            13 | 16 => *c == b':',
            19 => *c == b'Z',
            _ => c.is_ascii_digit(),
        });
    if !shape_ok {
        return None;
    }
    let num = |r: std::ops::Range<usize>| text[r].parse::<i64>().ok();
    let (year, month, day) = (num(0..4)?, num(5..7)?, num(8..10)?);
    let (h, m, s) = (num(11..13)?, num(14..16)?, num(17..19)?);
    if !(1..=12).contains(&month) || !(1..=31).contains(&day) || h > 23 || m > 59 || s > 60 || year < 1970 {
        return None;
    }
    // Days since 1970-01-01 from the civil date (Howard Hinnant's algorithm, the inverse of `rfc3339`).
    let y = if month <= 2 { year - 1 } else { year };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (month + 9) % 12;
    let doy = (153 * mp + 2) / 5 + day - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    let days = era * 146_097 + doe - 719_468;
    u64::try_from(days * 86_400 + h * 3600 + m * 60 + s).ok()
}

/// Formats seconds since the Unix epoch as RFC 3339 UTC.
fn rfc3339(secs: u64) -> String {
    let (days, rem) = (secs / 86_400, secs % 86_400);
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1_460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!("{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z", rem / 3600, rem % 3600 / 60, rem % 60)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry() -> ManifestEntry {
        ManifestEntry {
            table: "pairs".into(),
            shard: 12,
            first_unit: 120,
            units: 10,
            rows: 10,
            rows_by_status: BTreeMap::from([("ok".into(), 7), ("low_overlap".into(), 3)]),
            file: "pairs-000012.parquet".into(),
            bytes: 1234,
            blake3: "ab".into(),
            schema_version: "pairs/1".into(),
            config_hash: "cf".into(),
            code_version: "pointreggpt 0.1.0".into(),
            worker: "h:1".into(),
            created: utc_now(),
        }
    }

    #[test]
    fn rfc3339_known_dates() {
        assert_eq!(rfc3339(0), "1970-01-01T00:00:00Z");
        assert_eq!(rfc3339(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(rfc3339(1_709_251_199), "2024-02-29T23:59:59Z");
        assert_eq!(rfc3339(4_102_444_800), "2100-01-01T00:00:00Z");
        assert!(utc_now().starts_with("20"));
        for secs in [0, 951_782_400, 1_709_251_199, 4_102_444_800, 1_767_225_600 + 12_345] {
            assert_eq!(parse_rfc3339(&rfc3339(secs)), Some(secs));
        }
        for bad in ["", "2025-01-31", "2025-01-31T12:00:00+01:00", "2025-13-01T00:00:00Z", "2025-01-31T12:00:00.5Z"] {
            assert_eq!(parse_rfc3339(bad), None, "{bad}");
        }
    }

    #[test]
    fn file_names() {
        assert_eq!(shard_stem("pairs", 12), "pairs-000012");
        assert_eq!(parse_shard_file_name("pairs-000012.parquet", "parquet"), Some(("pairs", 12)));
        assert_eq!(parse_shard_file_name("my_labels-1234567.json", "json"), Some(("my_labels", 1_234_567)));
        assert_eq!(parse_shard_file_name("pairs-12.parquet", "parquet"), None);
        assert_eq!(parse_shard_file_name("pairs-000012.json", "parquet"), None);
        assert_eq!(parse_shard_file_name("Pairs-000012.parquet", "parquet"), None);
        assert_eq!(parse_object_file_name("pairs-000012-0a1b2c.parquet"), Some(("pairs", 12, "0a1b2c")));
        assert_eq!(parse_object_file_name("my_labels-1234567-x9.parquet"), Some(("my_labels", 1_234_567, "x9")));
        assert_eq!(parse_object_file_name("pairs-000012.parquet"), None);
        assert_eq!(parse_object_file_name("pairs-000012-AB.parquet"), None);
        assert_eq!(parse_object_file_name("pairs-12-ab.parquet"), None);
        assert!(check_table_name("labels").is_ok());
        assert!(check_table_name("a-b").is_err() && check_table_name("").is_err() && check_table_name("../x").is_err());
    }

    #[test]
    fn json_round_trip_and_checks() {
        let dir = tempfile::tempdir().unwrap();
        let e = entry();
        let path = dir.path().join("pairs-000012.json");
        std::fs::write(&path, e.to_json()).unwrap();
        assert_eq!(ManifestEntry::read(&path).unwrap(), e);
        // Under another name, the entry is refused.
        let other = dir.path().join("pairs-000013.json");
        std::fs::write(&other, e.to_json()).unwrap();
        assert!(ManifestEntry::read(&other).unwrap_err().to_string().contains("pairs-000013.json"));
        // Counts that do not add up, and junk.
        let bad = ManifestEntry { rows: 11, ..e.clone() };
        std::fs::write(&path, bad.to_json()).unwrap();
        assert!(ManifestEntry::read(&path).unwrap_err().to_string().contains("rows_by_status"));
        // An object-store entry names its unique object; another shard's object is refused.
        let object = ManifestEntry { file: "pairs-000012-00ff.parquet".into(), ..e.clone() };
        std::fs::write(&path, object.to_json()).unwrap();
        assert_eq!(ManifestEntry::read(&path).unwrap(), object);
        let foreign = ManifestEntry { file: "pairs-000013-00ff.parquet".into(), ..e.clone() };
        std::fs::write(&path, foreign.to_json()).unwrap();
        assert!(ManifestEntry::read(&path).unwrap_err().to_string().contains("unexpected shard file"));
        std::fs::write(&path, "{\"table\": ").unwrap();
        assert!(matches!(ManifestEntry::read(&path).unwrap_err(), Error::InputData { .. }));
    }
}
