//! Where a dataset lives: a local folder ([`local::LocalStore`]) or a prefix on an object store
//! (`s3://`, `gs://`, `az://`: [`object::ObjectDatasetStore`]), behind one small trait, [`DatasetStore`].
//!
//! The trait holds the few operations the dataset needs — read and create small text files
//! (`dataset.toml`, manifest entries), list a folder, read a shard, commit a shard, withdraw one, and
//! find and clean leftovers — so the commit protocol is written once per backend (`local.rs`,
//! `object_commit.rs`) and the rest of the code does not care where the bytes are. Names handed to a
//! store are relative to the dataset's root, `/`-separated (`manifest/pairs-000003.json`).

pub mod aws_profile;
pub mod local;
pub mod location;
pub mod object;
pub mod object_commit;
pub mod upload;

use super::manifest::ManifestEntry;
use crate::atomic::Published;
use crate::error::{Error, Result};
use arrow::array::RecordBatch;
use bytes::Bytes;
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The file at the dataset's root holding the resolved config and the `[dataset]` header.
pub const DATASET_FILE: &str = "dataset.toml";
/// Folder of the committed shard files.
pub const SHARDS_DIR: &str = "shards";
/// Folder of the manifest entries.
pub const MANIFEST_DIR: &str = "manifest";
/// Folder of the files being written (local) or of the upload records of shards being written (object store).
pub const TMP_DIR: &str = ".tmp";

/// One file of a listed folder.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Listed {
    /// File name inside the folder.
    pub name: String,
    /// Size in bytes.
    pub size: u64,
}

/// A leftover of an interrupted writer: a temporary file (local) or an upload record (object store).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Leftover {
    /// Where it is (path or URL).
    pub location: PathBuf,
    /// Its writer no longer runs (or, on an object store, it is older than [`object::STALE_RECORD_AGE`]),
    /// so nobody will finish it: [`DatasetStore::clean_stale`] removes it.
    pub stale: bool,
}

/// The storage operations of a dataset. Implemented by the local folder and by object stores.
pub trait DatasetStore: fmt::Debug + Send + Sync {
    /// The dataset's location as a path (local) or URL, for messages and for `Dataset::root`.
    fn root(&self) -> &Path;

    /// Where `rel` is (a path or URL), for messages.
    fn locate(&self, rel: &str) -> PathBuf {
        self.root().join(rel)
    }

    /// Checks that the dataset's location can be reached (object store: the bucket exists, the endpoint
    /// answers and the credentials are accepted), so a bad URL fails before any work is done.
    fn check_reachable(&self) -> Result<()> {
        Ok(())
    }

    /// Makes the dataset writable (local: creates its folders; object store: [`Self::check_reachable`]).
    fn prepare(&self) -> Result<()>;

    /// The text of `rel`, `None` when it does not exist.
    fn read_text(&self, rel: &str) -> Result<Option<String>>;

    /// Creates `rel` with `text` unless it exists (a racing creator may win: then `AlreadyThere`).
    fn create_text(&self, rel: &str, text: &str) -> Result<Published>;

    /// The texts of several small files, in order (reads run concurrently on an object store).
    fn read_texts(&self, rels: &[String]) -> Vec<Result<Option<String>>> {
        rels.iter().map(|r| self.read_text(r)).collect()
    }

    /// The files of folder `dir` (`shards`, `manifest`), sorted by name; empty if it does not exist.
    fn list(&self, dir: &str) -> Result<Vec<Listed>>;

    /// The bytes of `rel`.
    fn read_bytes(&self, rel: &str) -> Result<Bytes>;

    /// Commits `batch` as the shard `draft` describes: writes the shard file and then its manifest
    /// entry so that readers see all of it or nothing, whatever other writers of the same shard do.
    /// `draft` has every field but `file`, `bytes` and `blake3`; returns the entry now committed
    /// (another writer's, when it committed the shard first). The file has row groups of at most
    /// `row_group_rows` rows.
    fn commit(&self, draft: ManifestEntry, batch: &RecordBatch, row_group_rows: usize) -> Result<ManifestEntry>;

    /// Removes the manifest entry `rel` (nothing if it does not exist), so the shard no longer exists
    /// for readers and a resume redoes it; `file` is the shard file the entry named, which an object
    /// store removes too.
    fn retract(&self, rel: &str, file: &str) -> Result<()>;

    /// Temporary files or upload records of writers, running or not.
    fn leftovers(&self) -> Result<Vec<Leftover>>;

    /// Removes the stale leftovers (aborting their multipart uploads and removing the shard objects
    /// they were writing, unless committed); returns what was removed.
    fn clean_stale(&self) -> Result<Vec<PathBuf>>;

    /// Removes shard files that no manifest entry names and no writer is writing (`orphans`, file names
    /// in `shards/` listed *before* the leftovers and the manifest). A local folder keeps them: its
    /// shard files have fixed names, and the next commit of the shard adopts or replaces its file.
    fn remove_orphans(&self, orphans: &[String]) -> Result<Vec<PathBuf>>;

    /// How a query engine reaches the file `rel`: an absolute path (local) or a URL, and the object
    /// store to register for that URL's scheme and bucket.
    fn query_target(&self, rel: &str) -> Result<QueryTarget>;
}

/// Where a query engine reads a shard file from.
pub struct QueryTarget {
    /// Absolute path or `s3://bucket/key` URL of the file.
    pub url: String,
    /// The store to register with the query engine for `scheme://bucket` (none for a local path).
    pub store: Option<(url::Url, Arc<dyn object_store::ObjectStore>)>,
}

/// Opens the store of a dataset location: a folder path, `file://` URL, or an object-store URL
/// (`s3://bucket/prefix`, `gs://…`, `az://…`); text that looks like a URL but is not a supported one is
/// refused ([`location::classify`]).
pub fn open_store(location: &Path) -> Result<Arc<dyn DatasetStore>> {
    match location::classify(location)? {
        location::Location::Local(path) => Ok(Arc::new(local::LocalStore::new(path))),
        location::Location::Remote(text) => {
            let url = url::Url::parse(&text).map_err(|e| Error::config("dataset", format!("{text}: not a valid URL ({e})")))?;
            Ok(Arc::new(object::ObjectDatasetStore::open(&text, &url)?))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_schemes_are_refused_naming_the_url() {
        let err = open_store(Path::new("ftp://host/data")).unwrap_err().to_string();
        assert!(err.contains("ftp://host/data") && err.contains("s3://"), "{err}");
        let dir = tempfile::tempdir().unwrap();
        let url = format!("file://{}", dir.path().display());
        assert_eq!(open_store(Path::new(&url)).unwrap().root(), dir.path());
    }
}
