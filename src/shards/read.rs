//! Reading a dataset back: its committed shards (those with a valid manifest entry), the ones a resume
//! may skip, and their batches and rows.

use super::dataset::{Dataset, MANIFEST_DIR, PAIRS_TABLE, SHARDS_DIR};
use super::manifest::{check_table_name, parse_shard_file_name, ManifestEntry};
use super::pairs::batch_to_pairs;
use super::parquet_io::read_parquet_bytes;
use super::row::PairRow;
use crate::error::{Error, Result};
use arrow::array::RecordBatch;
use std::collections::BTreeMap;
use std::path::PathBuf;

impl Dataset {
    /// The committed shards of `table`, by shard index. A manifest entry that cannot be read, disagrees
    /// with its file name or has another config hash counts as not committed (a resume redoes the shard;
    /// [`Dataset::verify`] reports it).
    pub fn committed(&self, table: &str) -> Result<BTreeMap<u64, ManifestEntry>> {
        check_table_name(table)?;
        let scan = self.scan_manifest()?;
        for (path, why) in &scan.unreadable {
            tracing::warn!("{}: ignored, treated as not committed: {why}", path.display());
        }
        Ok(scan.entries.into_iter().filter(|((t, _), _)| t == table).map(|((_, s), e)| (s, e)).collect())
    }

    /// The committed shards of `table` that a resume may skip: those whose file exists with the size its
    /// manifest entry records (a cheap check: one listing; `verify` also hashes and decodes). The others
    /// are redone.
    pub fn resumable(&self, table: &str) -> Result<BTreeMap<u64, ManifestEntry>> {
        let mut committed = self.committed(table)?;
        let sizes: BTreeMap<String, u64> = self.store.list(SHARDS_DIR)?.into_iter().map(|l| (l.name, l.size)).collect();
        committed.retain(|_, e| {
            let ok = sizes.get(&e.file) == Some(&e.bytes);
            if !ok {
                let path = self.shard_file(e);
                tracing::warn!("{}: missing or not the size its manifest entry records; the shard will be redone", path.display());
            }
            ok
        });
        Ok(committed)
    }

    /// Where the file of a committed shard is (a path or URL).
    pub fn shard_file(&self, entry: &ManifestEntry) -> PathBuf {
        self.store.locate(&format!("{SHARDS_DIR}/{}", entry.file))
    }

    /// The batches of a committed shard. Errors name the file when it is missing, has another size than
    /// its manifest entry says, does not decode or has another row count.
    pub fn read_shard_batches(&self, entry: &ManifestEntry) -> Result<Vec<RecordBatch>> {
        let path = self.shard_file(entry);
        let bytes = self.store.read_bytes(&format!("{SHARDS_DIR}/{}", entry.file))?;
        if bytes.len() as u64 != entry.bytes {
            return Err(Error::input(
                &path,
                format!("{} bytes, its manifest entry says {} (run `pointreggpt verify`)", bytes.len(), entry.bytes),
            ));
        }
        let (_, batches) = read_parquet_bytes(bytes, &path)?;
        let rows: usize = batches.iter().map(|b| b.num_rows()).sum();
        if rows as u64 != entry.rows {
            return Err(Error::input(&path, format!("{rows} rows, its manifest entry says {}", entry.rows)));
        }
        Ok(batches)
    }

    /// Every row of the committed `pairs` shards, sorted by `unit_index`.
    pub fn read_pairs(&self) -> Result<Vec<PairRow>> {
        let mut rows = Vec::new();
        for entry in self.committed(PAIRS_TABLE)?.values() {
            let path = self.shard_file(entry);
            for batch in self.read_shard_batches(entry)? {
                rows.extend(batch_to_pairs(&batch).map_err(|e| Error::input(&path, e.to_string()))?);
            }
        }
        rows.sort_by_key(|r| r.unit_index);
        Ok(rows)
    }

    /// Reads every manifest entry: the valid ones by (table, shard), and the others with the reason.
    pub(crate) fn scan_manifest(&self) -> Result<ManifestScan> {
        let mut scan = ManifestScan::default();
        let mut named = Vec::new();
        for listed in self.store.list(MANIFEST_DIR)? {
            let path = self.store.locate(&format!("{MANIFEST_DIR}/{}", listed.name));
            match parse_shard_file_name(&listed.name, "json") {
                Some((table, shard)) => named.push((table.to_string(), shard, listed.name, path)),
                None => scan.unreadable.push((path, "not a manifest entry name (<table>-<shard:06>.json)".into())),
            }
        }
        let rels: Vec<String> = named.iter().map(|(_, _, name, _)| format!("{MANIFEST_DIR}/{name}")).collect();
        for ((table, shard, name, path), text) in named.into_iter().zip(self.store.read_texts(&rels)) {
            let parsed = match text {
                Ok(Some(t)) => ManifestEntry::parse(&t, &name, &path),
                Ok(None) => continue, // withdrawn since the listing
                Err(e) => {
                    if matches!(e, Error::Store { .. } | Error::Io { .. }) {
                        scan.read_errors.push(e.to_string());
                    }
                    Err(e)
                }
            };
            match parsed {
                Ok(e) if e.config_hash != self.header.config_hash => scan.unreadable.push((
                    path,
                    format!("config hash {} is not the dataset's {}", e.config_hash, self.header.config_hash),
                )),
                Ok(e) => {
                    scan.entries.insert((table, shard), e);
                }
                Err(e) => scan.unreadable.push((path, e.to_string())),
            }
        }
        Ok(scan)
    }
}

/// The manifest folder read by [`Dataset::scan_manifest`].
#[derive(Default)]
pub(crate) struct ManifestScan {
    pub entries: BTreeMap<(String, u64), ManifestEntry>,
    pub unreadable: Vec<(PathBuf, String)>,
    /// The entries among `unreadable` that could not be fetched (the store or the file system failed),
    /// as opposed to read and found invalid: a caller that must not take them as withdrawn stops on them.
    pub read_errors: Vec<String>,
}

/// The regular files of `dir` with their names, sorted (none if `dir` does not exist).
#[cfg(test)]
pub(crate) fn list_files(dir: &std::path::Path) -> Result<Vec<(PathBuf, String)>> {
    let store = super::store::local::LocalStore::new(dir.to_path_buf());
    Ok(super::store::DatasetStore::list(&store, "")?.into_iter().map(|l| (dir.join(&l.name), l.name)).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atomic::TempName;
    use crate::shards::dataset::tests::{rows, CONFIG};
    use crate::shards::pairs::pairs_to_batch;
    use crate::shards::parquet_io::write_parquet_bytes;
    use std::fs;

    #[test]
    fn uncommitted_files_are_invisible() {
        let dir = tempfile::tempdir().unwrap();
        let ds = Dataset::create_or_open(dir.path(), CONFIG, "h1").unwrap();
        ds.commit_pairs(0, 0, 4, &rows(0..4)).unwrap();
        // A complete shard file without manifest entry (a crash between the two renames).
        let bytes =
            write_parquet_bytes(&crate::shards::pairs_schema(), &[pairs_to_batch(&rows(4..8)).unwrap()], 64).unwrap();
        fs::write(ds.shard_path(PAIRS_TABLE, 1), &bytes).unwrap();
        // A temp file of a shard being written.
        let tmp = ds.tmp_dir().join(TempName::new("pairs-000002.parquet").file_name());
        fs::write(&tmp, &bytes).unwrap();
        // An unreadable manifest entry.
        fs::write(ds.manifest_path(PAIRS_TABLE, 3), "{").unwrap();
        let units: Vec<u64> = ds.read_pairs().unwrap().iter().map(|r| r.unit_index).collect();
        assert_eq!(units, [0, 1, 2, 3]);
        assert_eq!(ds.committed(PAIRS_TABLE).unwrap().keys().copied().collect::<Vec<_>>(), [0]);
    }
}
