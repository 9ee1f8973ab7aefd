//! `verify`: proves every committed shard is the file its manifest entry describes, and lists leftovers.

use super::dataset::{Dataset, PAIRS_TABLE, SHARDS_DIR};
use super::manifest::{parse_shard_file_name, ManifestEntry};
use super::parquet_io::read_parquet_bytes;
use crate::atomic::TempName;
use super::schema::{pairs_schema_mismatch, SCHEMA_VERSION_KEY};
use crate::error::{Error, Result};
use arrow::array::{Array, StringArray};
use std::collections::BTreeMap;
use std::fmt;
use std::path::PathBuf;

/// Something wrong with a committed shard or a manifest entry.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Problem {
    /// The shard file or manifest entry concerned.
    pub path: PathBuf,
    /// What is wrong.
    pub message: String,
    /// The (table, shard) whose manifest entry is concerned, when known (what `--repair` retracts).
    pub shard: Option<(String, u64)>,
}

/// What [`Dataset::verify`] found.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct VerifyReport {
    /// Intact committed shards per table.
    pub shards_ok: BTreeMap<String, u64>,
    /// Rows in the intact committed shards per table.
    pub rows_ok: BTreeMap<String, u64>,
    /// Committed shards that are missing, changed or undecodable, and unreadable manifest entries.
    pub problems: Vec<Problem>,
    /// Shard files without a valid manifest entry: invisible to readers, redone by a resume (or a commit
    /// in progress right now).
    pub orphans: Vec<PathBuf>,
    /// Temporary files of processes of this host that no longer run (`clean_stale_temps` removes them);
    /// on an object store, upload records of dead writers or older than an hour.
    pub stale_temps: Vec<PathBuf>,
    /// Temporary files (upload records) of running processes, of other hosts, or with unknown names.
    pub other_temps: Vec<PathBuf>,
}

/// What [`Dataset::repair`] did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RepairReport {
    /// Manifest entries withdrawn (their shards are redone by the next build run).
    pub retracted: usize,
    /// Stale temporary files (upload records, with their objects and multipart uploads) removed.
    pub cleaned: Vec<PathBuf>,
    /// Uncommitted shard objects removed (object stores only: a folder's orphans are adopted or
    /// replaced by the next commit of their shard).
    pub orphans_removed: Vec<PathBuf>,
}

impl VerifyReport {
    /// No problem with what is committed (orphans and temporary files are not problems).
    pub fn is_ok(&self) -> bool {
        self.problems.is_empty()
    }
}

impl fmt::Display for VerifyReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (table, shards) in &self.shards_ok {
            writeln!(f, "{table}: {shards} shards intact, {} rows", self.rows_ok.get(table).copied().unwrap_or(0))?;
        }
        for p in &self.problems {
            writeln!(f, "PROBLEM {}: {}", p.path.display(), p.message)?;
        }
        for o in &self.orphans {
            writeln!(f, "uncommitted shard file (no manifest entry): {}", o.display())?;
        }
        for t in &self.stale_temps {
            writeln!(f, "stale temporary file: {}", t.display())?;
        }
        for t in &self.other_temps {
            writeln!(f, "temporary file of a running or remote process: {}", t.display())?;
        }
        write!(f, "{}", if self.is_ok() { "verify: ok" } else { "verify: FAILED" })
    }
}

impl Dataset {
    /// Checks every manifest entry: its shard file exists, has the recorded size and blake3, decodes as
    /// Parquet with the recorded schema version (for `pairs`, exactly the pairs v1 columns), row count and
    /// rows per status. Also lists shard files without an entry and temporary files. Reads every
    /// committed byte once.
    pub fn verify(&self) -> Result<VerifyReport> {
        let mut report = VerifyReport::default();
        // Shard files first, then leftovers, then the manifest: a shard file that no entry names and no
        // leftover names at those later moments is not being written by anyone (see `store::object_commit`).
        let files = self.store.list(SHARDS_DIR)?;
        let leftovers = self.store.leftovers()?;
        let scan = self.scan_manifest()?;
        for (path, message) in scan.unreadable {
            let name = path.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default();
            let shard = parse_shard_file_name(&name, "json").map(|(t, s)| (t.to_string(), s));
            report.problems.push(Problem { path, message, shard });
        }
        for entry in scan.entries.values() {
            let path = self.shard_file(entry);
            match check_shard(self, entry) {
                Ok(()) => {
                    *report.shards_ok.entry(entry.table.clone()).or_default() += 1;
                    *report.rows_ok.entry(entry.table.clone()).or_default() += entry.rows;
                }
                Err(message) => report.problems.push(Problem { path, message, shard: Some((entry.table.clone(), entry.shard)) }),
            }
        }
        let named: std::collections::BTreeSet<&str> = scan.entries.values().map(|e| e.file.as_str()).collect();
        for file in files.iter().filter(|f| !named.contains(f.name.as_str())) {
            report.orphans.push(self.store.locate(&format!("{SHARDS_DIR}/{}", file.name)));
        }
        for left in leftovers {
            if left.stale {
                report.stale_temps.push(left.location);
            } else {
                report.other_temps.push(left.location);
            }
        }
        Ok(report)
    }

    /// Repairs what `report` (from [`Dataset::verify`]) found: withdraws the manifest entries of bad
    /// shards (a resume redoes exactly those), removes stale temporary files (on an object store: aborts
    /// the dead writers' multipart uploads and removes their uncommitted objects), and on an object
    /// store removes the uncommitted objects that no writer is writing.
    pub fn repair(&self, report: &VerifyReport) -> Result<RepairReport> {
        let mut done = RepairReport::default();
        for p in &report.problems {
            if let Some((table, shard)) = &p.shard {
                self.retract(table, *shard)?;
                done.retracted += 1;
            }
        }
        done.cleaned = self.clean_stale_temps()?;
        let name = |p: &PathBuf| p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let written: std::collections::BTreeSet<String> = report
            .stale_temps
            .iter()
            .chain(&report.other_temps)
            .filter_map(|p| TempName::parse(&name(p)).map(|t| t.target))
            .collect();
        let idle: Vec<String> = report.orphans.iter().map(name).filter(|n| !written.contains(n)).collect();
        done.orphans_removed = self.store.remove_orphans(&idle)?;
        Ok(done)
    }
}

/// Checks one committed shard against its entry; the error says what differs.
fn check_shard(ds: &Dataset, entry: &ManifestEntry) -> std::result::Result<(), String> {
    let path = ds.shard_file(entry);
    let bytes = ds
        .store()
        .read_bytes(&format!("{SHARDS_DIR}/{}", entry.file))
        .map_err(|e| format!("cannot read the committed shard: {e}"))?;
    if bytes.len() as u64 != entry.bytes {
        return Err(format!("{} bytes, the manifest entry says {}", bytes.len(), entry.bytes));
    }
    let hash = blake3::hash(&bytes).to_hex().to_string();
    if hash != entry.blake3 {
        return Err(format!("blake3 {hash}, the manifest entry says {}", entry.blake3));
    }
    let (schema, batches) = read_parquet_bytes(bytes, &path).map_err(|e| match e {
        Error::InputData { message, .. } => message,
        other => other.to_string(),
    })?;
    let version = schema.metadata().get(SCHEMA_VERSION_KEY).cloned().unwrap_or_default();
    if version != entry.schema_version {
        return Err(format!("schema version {version:?}, the manifest entry says {:?}", entry.schema_version));
    }
    if entry.table == PAIRS_TABLE {
        if let Some(m) = pairs_schema_mismatch(&schema) {
            return Err(format!("not the pairs schema: {m}"));
        }
    }
    let rows: usize = batches.iter().map(|b| b.num_rows()).sum();
    if rows as u64 != entry.rows {
        return Err(format!("{rows} rows, the manifest entry says {}", entry.rows));
    }
    if let Some(counts) = status_counts(&batches) {
        if counts != entry.rows_by_status {
            return Err(format!("rows per status {counts:?}, the manifest entry says {:?}", entry.rows_by_status));
        }
    }
    Ok(())
}

/// Rows per value of a utf8 `status` column, if the table has one.
fn status_counts(batches: &[arrow::array::RecordBatch]) -> Option<BTreeMap<String, u64>> {
    let mut counts = BTreeMap::new();
    for batch in batches {
        let status = batch.column_by_name("status")?.as_any().downcast_ref::<StringArray>()?;
        for i in 0..status.len() {
            *counts.entry(status.value(i).to_string()).or_insert(0) += 1;
        }
    }
    Some(counts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shards::pairs::tests::sample_row;
    use crate::shards::PairRow;
    use std::fs;

    fn dataset(dir: &std::path::Path) -> Dataset {
        let ds = Dataset::create_or_open(dir, "seed = 1\n", "h1").unwrap();
        for s in 0..3 {
            let rows: Vec<PairRow> = (s * 5..s * 5 + 5).map(sample_row).collect();
            ds.commit_pairs(s, s * 5, 5, &rows).unwrap();
        }
        ds
    }

    #[test]
    fn intact_dataset_verifies() {
        let dir = tempfile::tempdir().unwrap();
        let report = dataset(dir.path()).verify().unwrap();
        assert!(report.is_ok(), "{report}");
        assert_eq!(report.shards_ok[PAIRS_TABLE], 3);
        assert_eq!(report.rows_ok[PAIRS_TABLE], 15);
        assert!(report.orphans.is_empty() && report.stale_temps.is_empty() && report.other_temps.is_empty());
        assert!(report.to_string().ends_with("verify: ok"));
    }

    #[test]
    fn truncated_shard_is_reported() {
        let dir = tempfile::tempdir().unwrap();
        let ds = dataset(dir.path());
        let path = ds.shard_path(PAIRS_TABLE, 1);
        let bytes = fs::read(&path).unwrap();
        fs::write(&path, &bytes[..bytes.len() - 100]).unwrap();
        let report = ds.verify().unwrap();
        assert!(!report.is_ok());
        assert_eq!(report.problems.len(), 1, "{report}");
        assert_eq!(report.problems[0].path, path);
        assert!(report.problems[0].message.contains("bytes"), "{report}");
        assert_eq!(report.shards_ok[PAIRS_TABLE], 2);
        assert!(report.to_string().contains("verify: FAILED"));
        // Reading the truncated shard also fails, naming it.
        let entry = &ds.committed(PAIRS_TABLE).unwrap()[&1];
        let err = ds.read_shard_batches(entry).unwrap_err().to_string();
        assert!(err.contains("pairs-000001.parquet"), "{err}");
    }

    #[test]
    fn manifest_hash_mismatch_is_reported() {
        let dir = tempfile::tempdir().unwrap();
        let ds = dataset(dir.path());
        let mpath = ds.manifest_path(PAIRS_TABLE, 2);
        let mut entry = ManifestEntry::read(&mpath).unwrap();
        entry.blake3 = blake3::hash(b"something else").to_hex().to_string();
        fs::write(&mpath, entry.to_json()).unwrap();
        let report = ds.verify().unwrap();
        assert_eq!(report.problems.len(), 1, "{report}");
        assert_eq!(report.problems[0].path, ds.shard_path(PAIRS_TABLE, 2));
        assert!(report.problems[0].message.contains("blake3"), "{report}");
    }

    #[test]
    fn same_size_corruption_and_wrong_counts_are_reported() {
        let dir = tempfile::tempdir().unwrap();
        let ds = dataset(dir.path());
        // Flip one byte in the middle: same size, other hash.
        let path = ds.shard_path(PAIRS_TABLE, 0);
        let mut bytes = fs::read(&path).unwrap();
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0xff;
        fs::write(&path, &bytes).unwrap();
        // A manifest entry whose hash is right but whose status counts are wrong.
        let mpath = ds.manifest_path(PAIRS_TABLE, 1);
        let mut entry = ManifestEntry::read(&mpath).unwrap();
        let ok = entry.rows_by_status.remove("ok").unwrap();
        *entry.rows_by_status.get_mut("low_overlap").unwrap() += ok;
        fs::write(&mpath, entry.to_json()).unwrap();
        let report = ds.verify().unwrap();
        let messages: Vec<&str> = report.problems.iter().map(|p| p.message.as_str()).collect();
        assert_eq!(messages.len(), 2, "{report}");
        assert!(messages[0].contains("blake3") && messages[1].contains("status"), "{messages:?}");
    }

    #[test]
    fn orphans_broken_entries_and_temps_are_listed() {
        let dir = tempfile::tempdir().unwrap();
        let ds = dataset(dir.path());
        fs::remove_file(ds.manifest_path(PAIRS_TABLE, 2)).unwrap();
        fs::write(ds.manifest_path(PAIRS_TABLE, 1), "not json").unwrap();
        let dead = crate::atomic::TempName { pid: 4_194_304 + 5, ..crate::atomic::TempName::new("x") };
        fs::write(ds.tmp_dir().join(dead.file_name()), b"").unwrap();
        fs::write(ds.tmp_dir().join("unknown"), b"").unwrap();
        let report = ds.verify().unwrap();
        assert_eq!(report.orphans, [ds.shard_path(PAIRS_TABLE, 1), ds.shard_path(PAIRS_TABLE, 2)]);
        assert_eq!(report.problems.len(), 1);
        assert_eq!(report.problems[0].path, ds.manifest_path(PAIRS_TABLE, 1));
        assert_eq!(report.stale_temps, [ds.tmp_dir().join(dead.file_name())]);
        assert_eq!(report.other_temps, [ds.tmp_dir().join("unknown")]);
        assert_eq!(report.shards_ok[PAIRS_TABLE], 1);
    }
}
