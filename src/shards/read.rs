//! Reading a dataset back: its committed shards (those with a valid manifest entry), the ones a resume
//! may skip, and their batches and rows.

use super::dataset::{Dataset, MANIFEST_DIR, PAIRS_TABLE, SHARDS_DIR};
use super::manifest::{check_table_name, parse_shard_file_name, ManifestEntry};
use super::pairs::batch_to_pairs;
use super::parquet_io::read_parquet_file;
use super::row::PairRow;
use crate::error::{Error, Result};
use arrow::array::RecordBatch;
use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

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
    /// manifest entry records (a cheap check; `verify` also hashes and decodes). The others are redone.
    pub fn resumable(&self, table: &str) -> Result<BTreeMap<u64, ManifestEntry>> {
        let mut committed = self.committed(table)?;
        committed.retain(|_, e| {
            let path = self.root.join(SHARDS_DIR).join(&e.file);
            let ok = fs::metadata(&path).map(|m| m.len() == e.bytes).unwrap_or(false);
            if !ok {
                tracing::warn!("{}: missing or not the size its manifest entry records; the shard will be redone", path.display());
            }
            ok
        });
        Ok(committed)
    }


    /// The batches of a committed shard. Errors name the file when it is missing, has another size than
    /// its manifest entry says, does not decode or has another row count.
    pub fn read_shard_batches(&self, entry: &ManifestEntry) -> Result<Vec<RecordBatch>> {
        let path = self.root.join(SHARDS_DIR).join(&entry.file);
        let size = fs::metadata(&path).map_err(|e| Error::io(&path, e))?.len();
        if size != entry.bytes {
            return Err(Error::input(
                &path,
                format!("{size} bytes, its manifest entry says {} (run `pointreggpt verify`)", entry.bytes),
            ));
        }
        let (_, batches) = read_parquet_file(&path)?;
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
            let path = self.root.join(SHARDS_DIR).join(&entry.file);
            for batch in self.read_shard_batches(entry)? {
                rows.extend(batch_to_pairs(&batch).map_err(|e| Error::input(&path, e.to_string()))?);
            }
        }
        rows.sort_by_key(|r| r.unit_index);
        Ok(rows)
    }


    /// Reads every manifest entry: the valid ones by (table, shard), and the others with the reason.
    pub(crate) fn scan_manifest(&self) -> Result<ManifestScan> {
        let dir = self.root.join(MANIFEST_DIR);
        let mut scan = ManifestScan::default();
        for (path, name) in list_files(&dir)? {
            let Some((table, shard)) = parse_shard_file_name(&name, "json") else {
                scan.unreadable.push((path, "not a manifest entry name (<table>-<shard:06>.json)".into()));
                continue;
            };
            match ManifestEntry::read(&path) {
                Ok(e) if e.config_hash != self.header.config_hash => scan.unreadable.push((
                    path,
                    format!("config hash {} is not the dataset's {}", e.config_hash, self.header.config_hash),
                )),
                Ok(e) => {
                    scan.entries.insert((table.to_string(), shard), e);
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
}

/// The regular files of `dir` with their names, sorted (none if `dir` does not exist).
pub(crate) fn list_files(dir: &Path) -> Result<Vec<(PathBuf, String)>> {
    let entries = match fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(vec![]),
        Err(e) => return Err(Error::io(dir, e)),
    };
    let mut out = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| Error::io(dir, e))?;
        if entry.file_type().map_err(|e| Error::io(entry.path(), e))?.is_file() {
            out.push((entry.path(), entry.file_name().to_string_lossy().into_owned()));
        }
    }
    out.sort();
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atomic::TempName;
    use crate::shards::dataset::tests::{rows, CONFIG};
    use crate::shards::pairs::pairs_to_batch;
    use crate::shards::parquet_io::write_parquet_bytes;

    #[test]
    fn uncommitted_files_are_invisible() {
        let dir = tempfile::tempdir().unwrap();
        let ds = Dataset::create_or_open(dir.path(), CONFIG, "h1").unwrap();
        ds.commit_pairs(0, 0, 4, &rows(0..4)).unwrap();
        // A complete shard file without manifest entry (a crash between the two renames).
        let bytes =
            write_parquet_bytes(&crate::shards::pairs_schema(), &[pairs_to_batch(&rows(4..8)).unwrap()]).unwrap();
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
