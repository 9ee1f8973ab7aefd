//! Committing a shard ([`Dataset::commit_shard`]): Parquet to a temporary file, fsync, publish without
//! replacing, then its manifest entry the same way; and withdrawing one ([`Dataset::retract`]).

use crate::atomic::{write_atomic, Publish, Published};
use super::dataset::{Dataset, MANIFEST_DIR, PAIRS_TABLE, SHARDS_DIR};
use super::manifest::{check_table_name, shard_stem, utc_now, ManifestEntry};
use super::pairs::pairs_to_batch;
use super::parquet_io::{read_parquet_file, write_parquet_bytes};
use super::row::PairRow;
use super::schema::SCHEMA_VERSION_KEY;
use super::CODE_VERSION;
use crate::error::{Error, Result};
use arrow::array::RecordBatch;
use std::collections::BTreeMap;
use std::fs;
use std::path::Path;

impl Dataset {

    /// Commits `batch` as shard `shard` of `table` (work units `first_unit .. first_unit + units`):
    /// Parquet to a temporary file, fsync, publish into `shards/`, fsync the folder, then the manifest
    /// entry the same way. `rows_by_status` must add up to the batch's rows.
    ///
    /// A published shard file is never replaced while it is a valid Parquet file of the same schema
    /// and row count: a second committer of the same shard (committers of one dataset produce the same
    /// rows, timings aside) adopts it and writes a manifest entry describing that file, so the entry and
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
        // The folders may be missing in a copied dataset (`.tmp/` especially).
        for dir in [self.root.join(SHARDS_DIR), self.root.join(MANIFEST_DIR), self.tmp_dir()] {
            fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
        }
        let schema = batch.schema();
        let bytes = write_parquet_bytes(&schema, std::slice::from_ref(batch))?;
        let path = self.shard_path(table, shard);
        let (size, hash) = match write_atomic(&self.tmp_dir(), &path, &bytes, Publish::KeepExisting)? {
            Published::Written => (bytes.len() as u64, blake3::hash(&bytes)),
            Published::AlreadyThere => self.adopt_or_replace(&path, batch, &bytes)?,
        };
        let entry = ManifestEntry {
            table: table.to_string(),
            shard,
            first_unit,
            units,
            rows,
            rows_by_status,
            file: format!("{}.parquet", shard_stem(table, shard)),
            bytes: size,
            blake3: hash.to_hex().to_string(),
            schema_version: schema.metadata().get(SCHEMA_VERSION_KEY).cloned().unwrap_or_default(),
            config_hash: self.header.config_hash.clone(),
            code_version: CODE_VERSION.to_string(),
            worker: self.worker.clone(),
            created: utc_now(),
        };
        let manifest = self.manifest_path(table, shard);
        write_atomic(&self.tmp_dir(), &manifest, entry.to_json().as_bytes(), Publish::Replace)?;
        Ok(entry)
    }


    /// The shard file at `path` existed: keep it if it is a complete file like ours (same schema and
    /// row count), else replace it with `bytes`. Returns the size and hash of the file now in place.
    fn adopt_or_replace(&self, path: &Path, batch: &RecordBatch, bytes: &[u8]) -> Result<(u64, blake3::Hash)> {
        let existing = fs::read(path).map_err(|e| Error::io(path, e))?;
        let fits = match read_parquet_file(path) {
            Ok((schema, batches)) => {
                schema.fields() == batch.schema().fields()
                    && batches.iter().map(|b| b.num_rows()).sum::<usize>() == batch.num_rows()
            }
            Err(_) => false,
        };
        if fits {
            return Ok((existing.len() as u64, blake3::hash(&existing)));
        }
        tracing::warn!("{}: replacing an unusable uncommitted shard file", path.display());
        write_atomic(&self.tmp_dir(), path, bytes, Publish::Replace)?;
        Ok((bytes.len() as u64, blake3::hash(bytes)))
    }


    /// Commits `rows` as shard `shard` of the `pairs` table (see [`Dataset::commit_shard`]).
    pub fn commit_pairs(&self, shard: u64, first_unit: u64, units: u64, rows: &[PairRow]) -> Result<ManifestEntry> {
        let mut by_status = BTreeMap::new();
        for r in rows {
            *by_status.entry(r.status.as_str().to_string()).or_insert(0) += 1;
        }
        self.commit_shard(PAIRS_TABLE, shard, first_unit, units, &pairs_to_batch(rows)?, by_status)
    }


    /// Withdraws the manifest entry of a shard (the shard then no longer exists for readers and a resume
    /// redoes it). Used by `verify --repair` on shards that fail verification.
    pub fn retract(&self, table: &str, shard: u64) -> Result<()> {
        check_table_name(table)?;
        let path = self.manifest_path(table, shard);
        match fs::remove_file(&path) {
            Ok(()) => crate::atomic::sync_dir(&self.root.join(MANIFEST_DIR)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
            Err(e) => Err(Error::io(&path, e)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atomic::list_temps;
    use crate::shards::dataset::tests::{rows, CONFIG};
    use crate::shards::dataset::TMP_DIR;
    use crate::shards::read::list_files;
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
