//! Committing a shard ([`Dataset::commit_shard`]) through the dataset's store (a folder: temporary file,
//! fsync, publish without replacing; an object store: unique object, create-only manifest entry), and
//! withdrawing one ([`Dataset::retract`]).

use super::dataset::{Dataset, MANIFEST_DIR, PAIRS_TABLE};
use super::manifest::{check_table_name, shard_stem, utc_now, ManifestEntry};
use super::pairs::pairs_to_batch;
use super::row::PairRow;
use super::schema::SCHEMA_VERSION_KEY;
use super::CODE_VERSION;
use crate::error::{Error, Result};
use arrow::array::RecordBatch;
use std::collections::BTreeMap;

impl Dataset {
    /// Commits `batch` as shard `shard` of `table` (work units `first_unit .. first_unit + units`): the
    /// shard file, then its manifest entry, so that readers see the whole shard or nothing.
    /// `rows_by_status` must add up to the batch's rows.
    ///
    /// Committers of one dataset produce the same rows (timings aside). In a folder, a published shard
    /// file is never replaced while it is a valid Parquet file of the same schema and row count: a
    /// second committer adopts it and writes an entry describing that file. On an object store the
    /// first entry created wins and the other committers delete their objects. Either way the entry and
    /// the file always agree, however commits interleave.
    pub fn commit_shard(
        &self,
        table: &str,
        shard: u64,
        first_unit: u64,
        units: u64,
        batch: &RecordBatch,
        rows_by_status: BTreeMap<String, u64>,
    ) -> Result<ManifestEntry> {
        check_table_name(table)?;
        let rows = batch.num_rows() as u64;
        if rows_by_status.values().sum::<u64>() != rows {
            return Err(Error::InvalidArgument(format!(
                "shard {} of `{table}`: rows_by_status adds up to {}, the batch has {rows} rows",
                shard,
                rows_by_status.values().sum::<u64>()
            )));
        }
        let draft = ManifestEntry {
            table: table.to_string(),
            shard,
            first_unit,
            units,
            rows,
            rows_by_status,
            file: String::new(),
            bytes: 0,
            blake3: String::new(),
            schema_version: batch.schema().metadata().get(SCHEMA_VERSION_KEY).cloned().unwrap_or_default(),
            config_hash: self.header.config_hash.clone(),
            code_version: CODE_VERSION.to_string(),
            worker: self.worker.clone(),
            created: utc_now(),
        };
        self.store.commit(draft, batch, self.row_group_rows)
    }

    /// Commits `rows` as shard `shard` of the `pairs` table (see [`Dataset::commit_shard`]), in the
    /// dataset's schema version.
    pub fn commit_pairs(&self, shard: u64, first_unit: u64, units: u64, rows: &[PairRow]) -> Result<ManifestEntry> {
        let mut by_status = BTreeMap::new();
        for r in rows {
            *by_status.entry(r.status.as_str().to_string()).or_insert(0) += 1;
        }
        let mut batch = pairs_to_batch(rows)?;
        if self.header.schema_version != super::schema::SCHEMA_VERSION {
            batch = super::pairs_versions::downgrade(&batch, &self.header.schema_version)?; // a resumed dataset keeps its version
        }
        self.commit_shard(PAIRS_TABLE, shard, first_unit, units, &batch, by_status)
    }

    /// Withdraws the manifest entry of a shard (the shard then no longer exists for readers and a resume
    /// redoes it; on an object store its object is deleted too). Used by `verify --repair` on shards
    /// that fail verification.
    pub fn retract(&self, table: &str, shard: u64) -> Result<()> {
        check_table_name(table)?;
        let stem = shard_stem(table, shard);
        let rel = format!("{MANIFEST_DIR}/{stem}.json");
        let file = self
            .store
            .read_text(&rel)?
            .and_then(|t| serde_json::from_str::<ManifestEntry>(&t).ok())
            .map(|e| e.file)
            .filter(|f| f.starts_with(&format!("{stem}-")))
            .unwrap_or_default();
        self.store.retract(&rel, &file)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atomic::list_temps;
    use crate::shards::dataset::tests::{rows, CONFIG};
    use crate::shards::dataset::{SHARDS_DIR, TMP_DIR};
    use crate::shards::read::list_files;
    use std::fs;
    use crate::shards::row::Status;

    #[test]
    fn commit_then_committed_and_read() {
        let dir = tempfile::tempdir().unwrap();
        let ds = Dataset::create_or_open(dir.path(), CONFIG, "h1").unwrap().with_worker("w3");
        fs::remove_dir(ds.tmp_dir()).unwrap(); // as in a copy without hidden folders
        let shard1 = rows(10..20);
        let shard0 = rows(0..10);
        let e1 = ds.commit_pairs(1, 10, 10, &shard1).unwrap();
        ds.commit_pairs(0, 0, 10, &shard0).unwrap();
        let committed = ds.committed(PAIRS_TABLE).unwrap();
        assert_eq!(committed.keys().copied().collect::<Vec<_>>(), [0, 1]);
        assert_eq!(committed[&1], e1);
        assert_eq!(e1.worker, "w3");
        assert_eq!(e1.rows, 10);
        let expected = [("input_error", 3), ("low_overlap", 2), ("ok", 2), ("too_few_points", 3)];
        assert_eq!(
            e1.rows_by_status,
            expected.map(|(k, v)| (k.to_string(), v)).into(),
            "units 10..20, status = unit % 4"
        );
        let file = fs::read(ds.shard_path(PAIRS_TABLE, 1)).unwrap();
        assert_eq!(e1.bytes, file.len() as u64);
        assert_eq!(e1.blake3, blake3::hash(&file).to_hex().to_string());
        let all: Vec<PairRow> = shard0.into_iter().chain(shard1).collect();
        assert_eq!(ds.read_pairs().unwrap(), all, "rows come back sorted by unit_index");
        assert!(ds.committed("labels").unwrap().is_empty());
        assert!(list_temps(&ds.tmp_dir()).unwrap().is_empty());
    }

    #[test]
    fn recommitting_adopts_the_published_file() {
        let dir = tempfile::tempdir().unwrap();
        let ds = Dataset::create_or_open(dir.path(), CONFIG, "h1").unwrap();
        let first = ds.commit_pairs(0, 0, 4, &rows(0..4)).unwrap();
        // Same rows, other timings: other bytes, but the published file stays and the entry describes it.
        let mut again = rows(0..4);
        again[0].timings.push(crate::shards::StageTiming { stage: "late".into(), ms: 9.0 });
        let second = ds.commit_pairs(0, 0, 4, &again).unwrap();
        assert_eq!(second.blake3, first.blake3);
        assert_eq!(ds.read_pairs().unwrap(), rows(0..4));
        // A garbage uncommitted file in the way is replaced.
        fs::write(ds.shard_path(PAIRS_TABLE, 1), b"garbage").unwrap();
        let e = ds.commit_pairs(1, 4, 4, &rows(4..8)).unwrap();
        assert_eq!(e.bytes, fs::metadata(ds.shard_path(PAIRS_TABLE, 1)).unwrap().len());
        assert_eq!(ds.read_pairs().unwrap().len(), 8);
    }

    #[test]
    fn rows_by_status_must_add_up() {
        let dir = tempfile::tempdir().unwrap();
        let ds = Dataset::create_or_open(dir.path(), CONFIG, "h1").unwrap();
        let batch = pairs_to_batch(&rows(0..3)).unwrap();
        let wrong = BTreeMap::from([(Status::Ok.as_str().to_string(), 2)]);
        assert!(ds.commit_shard(PAIRS_TABLE, 0, 0, 3, &batch, wrong).is_err());
        assert!(ds.commit_shard("bad-name", 0, 0, 3, &batch, BTreeMap::new()).is_err());
        assert!(!ds.shard_path(PAIRS_TABLE, 0).exists());
    }

    #[test]
    fn concurrent_commits_of_one_shard_leave_one_file_and_one_entry() {
        let dir = tempfile::tempdir().unwrap();
        let ds = Dataset::create_or_open(dir.path(), CONFIG, "h1").unwrap();
        let shard = rows(0..6);
        let entries: Vec<ManifestEntry> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..2).map(|_| s.spawn(|| ds.commit_pairs(5, 30, 6, &shard).unwrap())).collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        assert_eq!(entries[0].blake3, entries[1].blake3);
        let names = |d: &str| list_files(&dir.path().join(d)).unwrap().into_iter().map(|(_, n)| n).collect::<Vec<_>>();
        assert_eq!(names(SHARDS_DIR), ["pairs-000005.parquet"]);
        assert_eq!(names(MANIFEST_DIR), ["pairs-000005.json"]);
        assert!(names(TMP_DIR).is_empty());
        assert_eq!(ds.read_pairs().unwrap(), shard);
        assert!(ds.verify().unwrap().is_ok());
    }
}
