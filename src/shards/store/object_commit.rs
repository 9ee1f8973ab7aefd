//! The commit protocol on an object store, where nothing can be renamed:
//! 1. put an upload record `.tmp/<host>~<pid>~<object>~<nonce>.tmp` naming the shard object;
//! 2. write the shard as an immutable object under a unique name, `shards/<table>-<shard:06>-<id>.parquet`
//!    (one put, or a multipart upload whose id is added to the record first);
//! 3. commit it by creating its manifest entry `manifest/<table>-<shard:06>.json` with a create-only put
//!    (`If-None-Match: *`). If another writer committed the shard first, this writer deletes its own object
//!    and adopts that entry; an entry whose object is missing or has another size is replaced with a
//!    conditional put on its ETag (`If-Match`), so two writers never both replace it;
//! 4. delete the upload record.
//!
//! A writer killed at any point leaves its upload record (and perhaps an uncommitted object or an
//! incomplete multipart upload): [`DatasetStore::clean_stale`](super::DatasetStore::clean_stale) aborts
//! the upload and removes the object unless an entry names it. An object that no entry names and no
//! record names is garbage (its writer finished); `verify --repair` removes it.

use super::object::ObjectDatasetStore;
use super::upload::{write_batch, ShardUpload, UploadRecord, PART_SIZE};
use super::{DatasetStore, MANIFEST_DIR, SHARDS_DIR, TMP_DIR};
use crate::atomic::{hostname, TempName};
use crate::error::{Error, Result};
use crate::shards::manifest::{parse_object_file_name, shard_stem, ManifestEntry};
use arrow::array::RecordBatch;
use bytes::Bytes;
use object_store::{ObjectStoreExt, PutMode, PutOptions, UpdateVersion};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};

/// How often a writer retries replacing a broken manifest entry that another writer changed meanwhile.
const REPLACE_TRIES: usize = 5;

/// A fresh object id: 16 hex digits of a hash of (host, pid, time, counter), unique among writers.
pub fn object_id() -> String {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let t = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0);
    let h = blake3::hash(format!("{}~{}~{t}~{n}", hostname(), std::process::id()).as_bytes());
    h.to_hex()[..16].to_string()
}

impl ObjectDatasetStore {
    /// Commits `batch` as described in the module docs (row groups of at most `row_group_rows` rows), in
    /// parts of [`PART_SIZE`] above that size.
    pub(super) fn commit_object(&self, entry: ManifestEntry, batch: &RecordBatch, row_group_rows: usize) -> Result<ManifestEntry> {
        self.commit_object_with(entry, batch, PART_SIZE, row_group_rows)
    }

    /// [`Self::commit_object`] with parts of `part_size` bytes (tests exercise multipart uploads with it).
    pub fn commit_object_with(
        &self,
        mut entry: ManifestEntry,
        batch: &RecordBatch,
        part_size: usize,
        row_group_rows: usize,
    ) -> Result<ManifestEntry> {
        let stem = shard_stem(&entry.table, entry.shard);
        let file = format!("{stem}-{}.parquet", object_id());
        let object_rel = format!("{SHARDS_DIR}/{file}");
        let record_rel = format!("{TMP_DIR}/{}", TempName::new(&file).file_name());
        let record = UploadRecord { object: file.clone(), upload_id: None };
        let json = serde_json::to_vec(&record).expect("an upload record serializes");
        let record_key = self.key(&record_rel);
        self.run(self.store.put(&record_key, Bytes::from(json).into()))?.map_err(|e| self.err(&record_rel, e))?;

        let upload = ShardUpload::new(self.store.clone(), self.multipart.clone(), self.key(&object_rel), record_key, record, part_size);
        let url = self.locate(&object_rel).display().to_string();
        let uploaded = self.run(write_batch(upload, batch, &url, row_group_rows))??;
        (entry.file, entry.bytes, entry.blake3) = (file.clone(), uploaded.bytes, uploaded.blake3.to_hex().to_string());

        let committed = self.publish_entry(&format!("{MANIFEST_DIR}/{stem}.json"), entry)?;
        if committed.file != file {
            tracing::warn!(
                "{}: another writer ({}) committed it first; this writer's object is removed",
                self.locate(&format!("{MANIFEST_DIR}/{stem}.json")).display(),
                committed.worker
            );
            if let Err(e) = self.delete(&object_rel) {
                tracing::warn!("{e}; `pointreggpt verify --repair` removes the uncommitted object");
            }
        }
        // The shard is committed: a record that cannot be removed now is removed as stale later.
        if let Err(e) = self.delete(&record_rel) {
            tracing::warn!("{e}; `pointreggpt verify --repair` removes the upload record");
        }
        Ok(committed)
    }

    /// Creates the manifest entry `rel` unless a valid one exists (then returns that one); replaces a
    /// broken one only if nobody changed it since it was read.
    fn publish_entry(&self, rel: &str, entry: ManifestEntry) -> Result<ManifestEntry> {
        let key = self.key(rel);
        let mut mode = PutMode::Create;
        for _ in 0..REPLACE_TRIES {
            let opts = PutOptions { mode: mode.clone(), ..Default::default() };
            match self.run(self.store.put_opts(&key, Bytes::from(entry.to_json()).into(), opts))? {
                Ok(_) => return Ok(entry),
                Err(object_store::Error::AlreadyExists { .. } | object_store::Error::Precondition { .. }) => {}
                Err(e) => return Err(self.err(rel, e)),
            }
            let got = self.run(async { let g = self.store.get(&key).await?; let meta = g.meta.clone(); Ok::<_, object_store::Error>((meta, g.bytes().await?)) })?;
            let (meta, bytes) = match got {
                Ok(x) => x,
                Err(object_store::Error::NotFound { .. }) => {
                    mode = PutMode::Create; // withdrawn meanwhile
                    continue;
                }
                Err(e) => return Err(self.err(rel, e)),
            };
            let text = String::from_utf8_lossy(&bytes);
            if let Ok(existing) = ManifestEntry::parse(&text, rel.rsplit('/').next().unwrap_or(rel), &self.locate(rel)) {
                if existing.config_hash == entry.config_hash && self.object_size(&existing.file)? == Some(existing.bytes) {
                    return Ok(existing);
                }
            }
            tracing::warn!("{}: replacing a manifest entry whose shard object is missing or changed", self.locate(rel).display());
            mode = PutMode::Update(UpdateVersion { e_tag: meta.e_tag, version: meta.version });
        }
        Err(Error::Store { url: self.locate(rel).display().to_string(), message: format!("other writers kept changing the entry ({REPLACE_TRIES} tries)") })
    }

    /// The size of `shards/<file>`, `None` if it does not exist.
    fn object_size(&self, file: &str) -> Result<Option<u64>> {
        let rel = format!("{SHARDS_DIR}/{file}");
        match self.run(self.store.head(&self.key(&rel)))? {
            Ok(m) => Ok(Some(m.size)),
            Err(object_store::Error::NotFound { .. }) => Ok(None),
            Err(e) => Err(self.err(&rel, e)),
        }
    }

    /// Whether a manifest entry names the object `shards/<file>` now.
    fn is_committed(&self, file: &str) -> Result<bool> {
        let Some((table, shard, _)) = parse_object_file_name(file) else { return Ok(false) };
        let rel = format!("{MANIFEST_DIR}/{}.json", shard_stem(table, shard));
        Ok(self.read_text(&rel)?.and_then(|t| serde_json::from_str::<ManifestEntry>(&t).ok()).is_some_and(|e| e.file == file))
    }

    /// Removes the stale upload records: aborts their multipart upload, removes their object unless an
    /// entry names it, then the record.
    pub(super) fn clean_stale_records(&self) -> Result<Vec<PathBuf>> {
        let mut removed = Vec::new();
        for left in self.leftovers()?.into_iter().filter(|l| l.stale) {
            let name = left.location.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            let record_rel = format!("{TMP_DIR}/{name}");
            let record: UploadRecord = self.read_text(&record_rel)?.and_then(|t| serde_json::from_str(&t).ok()).unwrap_or_default();
            let object = TempName::parse(&name).map(|n| n.target).filter(|t| parse_object_file_name(t).is_some());
            if let Some(object) = object.or((!record.object.is_empty()).then_some(record.object.clone())) {
                let object_rel = format!("{SHARDS_DIR}/{object}");
                if let Some(id) = &record.upload_id {
                    match self.run(self.multipart.abort_multipart(&self.key(&object_rel), id))? {
                        Ok(()) | Err(object_store::Error::NotFound { .. }) => {}
                        Err(e) => return Err(self.err(&object_rel, e)),
                    }
                }
                if !self.is_committed(&object)? {
                    if self.object_size(&object)?.is_some() {
                        self.delete(&object_rel)?;
                        removed.push(self.locate(&object_rel));
                    } else if record.upload_id.is_some() {
                        // Azure has no upload to abort (object_store's abort is a no-op there): the
                        // uploaded blocks belong to the blob name, invisible to listings and HEAD until
                        // committed. Deleting the name drops them (on S3 this deletes nothing).
                        self.delete(&object_rel)?;
                    }
                }
            }
            self.delete(&record_rel)?;
            removed.push(left.location);
        }
        Ok(removed)
    }

    /// Deletes the objects `shards/<name>` of `orphans` (found unnamed by entries and records).
    pub(super) fn remove_orphan_objects(&self, orphans: &[String]) -> Result<Vec<PathBuf>> {
        let mut removed = Vec::new();
        for name in orphans {
            let rel = format!("{SHARDS_DIR}/{name}");
            self.delete(&rel)?;
            removed.push(self.locate(&rel));
        }
        Ok(removed)
    }
}
