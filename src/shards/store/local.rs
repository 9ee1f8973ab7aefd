//! A dataset in a local (or shared POSIX) folder: temporary file, fsync, publish without replacing
//! (hard link), fsync the folder; then the manifest entry the same way.

use super::{DatasetStore, Leftover, Listed, QueryTarget, MANIFEST_DIR, SHARDS_DIR, TMP_DIR};
use crate::atomic::{list_temps, write_atomic, Publish, Published};
use crate::error::{Error, Result};
use crate::shards::manifest::{shard_stem, ManifestEntry};
use crate::shards::parquet_io::{read_parquet_file, write_parquet_bytes};
use arrow::array::RecordBatch;
use bytes::Bytes;
use std::fs;
use std::path::{Path, PathBuf};

/// The dataset folder at `root`.
#[derive(Clone, Debug)]
pub struct LocalStore {
    root: PathBuf,
}

impl LocalStore {
    pub fn new(root: PathBuf) -> LocalStore {
        LocalStore { root }
    }

    fn tmp_dir(&self) -> PathBuf {
        self.root.join(TMP_DIR)
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
}

impl DatasetStore for LocalStore {
    fn root(&self) -> &Path {
        &self.root
    }

    fn prepare(&self) -> Result<()> {
        for dir in [self.root.clone(), self.root.join(SHARDS_DIR), self.root.join(MANIFEST_DIR), self.tmp_dir()] {
            fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
        }
        Ok(())
    }

    fn read_text(&self, rel: &str) -> Result<Option<String>> {
        let path = self.root.join(rel);
        match fs::read_to_string(&path) {
            Ok(t) => Ok(Some(t)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(Error::io(&path, e)),
        }
    }

    /// Creates `rel` (and its folder, e.g. `_delta_log/`) without replacing: temporary file, hard link.
    fn create_text(&self, rel: &str, text: &str) -> Result<Published> {
        let target = self.root.join(rel);
        for dir in [self.tmp_dir(), target.parent().map(Path::to_path_buf).unwrap_or_default()] {
            if !dir.as_os_str().is_empty() && !dir.is_dir() {
                fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
            }
        }
        write_atomic(&self.tmp_dir(), &target, text.as_bytes(), Publish::KeepExisting)
    }

    fn list(&self, dir: &str) -> Result<Vec<Listed>> {
        let dir = self.root.join(dir);
        let entries = match fs::read_dir(&dir) {
            Ok(e) => e,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(vec![]),
            Err(e) => return Err(Error::io(&dir, e)),
        };
        let mut out = Vec::new();
        for entry in entries {
            let entry = entry.map_err(|e| Error::io(&dir, e))?;
            let meta = entry.metadata().map_err(|e| Error::io(entry.path(), e))?;
            if meta.is_file() {
                out.push(Listed { name: entry.file_name().to_string_lossy().into_owned(), size: meta.len() });
            }
        }
        out.sort_by(|a, b| a.name.cmp(&b.name));
        Ok(out)
    }

    fn read_bytes(&self, rel: &str) -> Result<Bytes> {
        let path = self.root.join(rel);
        fs::read(&path).map(Bytes::from).map_err(|e| Error::io(&path, e))
    }

    fn commit(&self, mut entry: ManifestEntry, batch: &RecordBatch, row_group_rows: usize) -> Result<ManifestEntry> {
        // The folders may be missing in a copied dataset (`.tmp/` especially).
        self.prepare()?;
        let stem = shard_stem(&entry.table, entry.shard);
        let bytes = write_parquet_bytes(&batch.schema(), std::slice::from_ref(batch), row_group_rows)?;
        let path = self.root.join(SHARDS_DIR).join(format!("{stem}.parquet"));
        let (size, hash) = match write_atomic(&self.tmp_dir(), &path, &bytes, Publish::KeepExisting)? {
            Published::Written => (bytes.len() as u64, blake3::hash(&bytes)),
            Published::AlreadyThere => self.adopt_or_replace(&path, batch, &bytes)?,
        };
        (entry.file, entry.bytes, entry.blake3) = (format!("{stem}.parquet"), size, hash.to_hex().to_string());
        let manifest = self.root.join(MANIFEST_DIR).join(format!("{stem}.json"));
        write_atomic(&self.tmp_dir(), &manifest, entry.to_json().as_bytes(), Publish::Replace)?;
        Ok(entry)
    }

    fn retract(&self, rel: &str, _file: &str) -> Result<()> {
        let path = self.root.join(rel);
        match fs::remove_file(&path) {
            Ok(()) => crate::atomic::sync_dir(&self.root.join(MANIFEST_DIR)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
            Err(e) => Err(Error::io(&path, e)),
        }
    }

    fn leftovers(&self) -> Result<Vec<Leftover>> {
        Ok(list_temps(&self.tmp_dir())?
            .into_iter()
            .map(|(location, name)| Leftover { location, stale: name.is_some_and(|n| n.is_stale()) })
            .collect())
    }

    /// Removes the temporary files left on this host by processes that no longer run; other live
    /// processes' (and other hosts') files stay.
    fn clean_stale(&self) -> Result<Vec<PathBuf>> {
        let mut removed = Vec::new();
        for left in self.leftovers()? {
            if left.stale {
                match fs::remove_file(&left.location) {
                    Ok(()) => removed.push(left.location),
                    Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                    Err(e) => return Err(Error::io(&left.location, e)),
                }
            }
        }
        Ok(removed)
    }

    fn remove_orphans(&self, _orphans: &[String]) -> Result<Vec<PathBuf>> {
        Ok(Vec::new())
    }

    fn query_target(&self, rel: &str) -> Result<QueryTarget> {
        let path = self.root.join(rel);
        let abs = fs::canonicalize(&path).map_err(|e| Error::io(&path, e))?;
        Ok(QueryTarget { url: abs.to_string_lossy().into_owned(), store: None })
    }
}
