//! The dataset: opening or creating it (`dataset.toml` with its `[dataset]` header, refusing another
//! config) in a folder or at an object-store URL ([`super::store`]), its paths, and its temporary files.
//! Committing shards is [`super::commit`], reading them back [`super::read`], checking them [`super::verify`].
//!
//! See the module docs of [`crate::shards`] for the layout and the commit protocol.

use super::config_diff::config_differences;
use super::manifest::{shard_stem, utc_now};
use super::schema::{pairs_schema_of, SCHEMA_VERSION};
use super::CODE_VERSION;
use super::parquet_io::ROW_GROUP_ROWS;
pub use super::store::{DATASET_FILE, MANIFEST_DIR, SHARDS_DIR, TMP_DIR};
use super::store::{open_store, DatasetStore};
use crate::atomic::{hostname, Published};
use crate::error::{Error, Result};
use std::path::{Path, PathBuf};
use std::sync::Arc;
/// The table of [`PairRow`]s.
pub const PAIRS_TABLE: &str = "pairs";

/// The `[dataset]` table of `dataset.toml`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DatasetHeader {
    /// blake3 of the resolved pipeline config, hex: every shard of the dataset was built with it.
    pub config_hash: String,
    /// Schema version of the pairs table (`pairs/2`; `pairs/1` for datasets built before it).
    pub schema_version: String,
    /// Code version that created the dataset (each shard records its own in the manifest).
    pub code_version: String,
    /// UTC creation time, RFC 3339.
    pub created: String,
}

/// A dataset (a folder or an object-store prefix), opened for committing shards or for reading them.
#[derive(Clone, Debug)]
pub struct Dataset {
    pub(super) store: Arc<dyn DatasetStore>,
    pub(super) header: DatasetHeader,
    /// Worker id recorded in manifest entries.
    pub(super) worker: String,
    /// Most rows in one row group of the shard files this handle commits.
    pub(super) row_group_rows: usize,
}

impl Dataset {
    /// Opens the dataset at `root`, creating it (folders and `dataset.toml`) on first use.
    ///
    /// `resolved_config_toml` is the resolved pipeline config, stored verbatim below the `[dataset]`
    /// header; it may not have a top-level `dataset` key. When the dataset exists with another
    /// `config_hash`, this is refused with a message naming the differing config keys. Processes racing
    /// to create the same dataset with the same config all succeed.
    pub fn create_or_open(root: impl AsRef<Path>, resolved_config_toml: &str, config_hash: &str) -> Result<Dataset> {
        if config_hash.is_empty() {
            return Err(Error::InvalidArgument("empty config hash".into()));
        }
        let config: toml::Table = resolved_config_toml
            .parse()
            .map_err(|e| Error::config("config", format!("the resolved config is not valid TOML: {e}")))?;
        if config.contains_key("dataset") {
            return Err(Error::config("dataset", "the top-level key `dataset` is reserved for the dataset header"));
        }
        let store = open_store(root.as_ref())?;
        store.prepare()?;
        if store.read_text(DATASET_FILE)?.is_none() {
            let header = DatasetHeader {
                config_hash: config_hash.to_string(),
                schema_version: SCHEMA_VERSION.to_string(),
                code_version: CODE_VERSION.to_string(),
                created: utc_now(),
            };
            let text = dataset_file_text(&header, resolved_config_toml);
            // Never replace: a racing creator may have published first; then compare with its file.
            if store.create_text(DATASET_FILE, &text)? == Published::Written {
                return Ok(Dataset::with_header(store, header));
            }
        }
        let (header, recorded) = read_dataset_file(store.as_ref())?;
        if header.config_hash != config_hash {
            return Err(config_mismatch(store.root(), &header, &recorded, &config, config_hash));
        }
        check_schema_version(store.as_ref(), &header)?;
        Ok(Dataset::with_header(store, header))
    }

    /// Opens an existing dataset for reading (or committing with its recorded config): a folder, or an
    /// object-store URL (`s3://bucket/prefix`, `gs://…`, `az://…`).
    pub fn open(root: impl AsRef<Path>) -> Result<Dataset> {
        let store = open_store(root.as_ref())?;
        store.check_reachable()?;
        let (header, _) = read_dataset_file(store.as_ref())?;
        check_schema_version(store.as_ref(), &header)?;
        Ok(Dataset::with_header(store, header))
    }

    fn with_header(store: Arc<dyn DatasetStore>, header: DatasetHeader) -> Dataset {
        Dataset { store, header, worker: format!("{}:{}", hostname(), std::process::id()), row_group_rows: ROW_GROUP_ROWS }
    }

    /// Sets the worker id recorded in manifest entries (default `<host>:<pid>`).
    pub fn with_worker(mut self, worker: impl Into<String>) -> Dataset {
        self.worker = worker.into();
        self
    }

    /// Sets the most rows in one row group of the shard files committed through this handle (default
    /// [`ROW_GROUP_ROWS`]). It changes how files are laid out, not what they hold.
    pub fn with_row_group_rows(mut self, rows: usize) -> Dataset {
        self.row_group_rows = rows.max(1);
        self
    }

    /// The dataset folder, or its URL (as a path) on an object store.
    pub fn root(&self) -> &Path {
        self.store.root()
    }

    /// Where the dataset's files are.
    pub fn store(&self) -> &dyn DatasetStore {
        self.store.as_ref()
    }

    /// The `[dataset]` header of `dataset.toml`.
    pub fn header(&self) -> &DatasetHeader {
        &self.header
    }

    /// Where shard `shard` of `table` lives in a folder (committed or not). On an object store the
    /// shard's object has a unique name: its manifest entry's `file`.
    pub fn shard_path(&self, table: &str, shard: u64) -> PathBuf {
        self.store.locate(&format!("{SHARDS_DIR}/{}.parquet", shard_stem(table, shard)))
    }

    /// Where the manifest entry of shard `shard` of `table` lives.
    pub fn manifest_path(&self, table: &str, shard: u64) -> PathBuf {
        self.store.locate(&format!("{MANIFEST_DIR}/{}.json", shard_stem(table, shard)))
    }

    /// The folder of temporary files (upload records on an object store).
    pub fn tmp_dir(&self) -> PathBuf {
        self.store.locate(TMP_DIR)
    }

    /// Removes the temporary files left by processes that no longer run (on an object store: upload
    /// records of dead writers, with their uncommitted objects and incomplete multipart uploads); live
    /// processes' (and, locally, other hosts') files stay. Returns what was removed.
    pub fn clean_stale_temps(&self) -> Result<Vec<PathBuf>> {
        self.store.clean_stale()
    }
}
/// `dataset.toml`: a comment, the header as dotted `dataset.*` keys (they must precede every table), then
/// the resolved config verbatim.
fn dataset_file_text(header: &DatasetHeader, config: &str) -> String {
    let q = |s: &str| toml::Value::String(s.to_string()).to_string();
    format!(
        "# pointreggpt dataset. The [dataset] header, then the resolved pipeline config every shard was built with.\n\
         # Do not edit: shards and manifest entries refer to this config by its hash.\n\
         dataset.config_hash = {}\n\
         dataset.schema_version = {}\n\
         dataset.code_version = {}\n\
         dataset.created = {}\n\n{config}",
        q(&header.config_hash),
        q(&header.schema_version),
        q(&header.code_version),
        q(&header.created),
    )
}

/// The header and the recorded config (without the `dataset` table) of the dataset in `store`.
fn read_dataset_file(store: &dyn DatasetStore) -> Result<(DatasetHeader, toml::Table)> {
    let path = store.locate(DATASET_FILE);
    let Some(text) = store.read_text(DATASET_FILE)? else {
        return Err(Error::input(store.root(), format!("not a pointreggpt dataset: it has no {DATASET_FILE}")));
    };
    let mut table: toml::Table = text.parse().map_err(|e| Error::input(&path, format!("not valid TOML: {e}")))?;
    let Some(toml::Value::Table(head)) = table.remove("dataset") else {
        return Err(Error::input(&path, "no [dataset] header table: not a pointreggpt dataset file"));
    };
    let field = |k: &str| -> Result<String> {
        head.get(k)
            .and_then(|v| v.as_str())
            .map(str::to_string)
            .ok_or_else(|| Error::input(&path, format!("[dataset] header has no string `{k}`")))
    };
    let header = DatasetHeader {
        config_hash: field("config_hash")?,
        schema_version: field("schema_version")?,
        code_version: field("code_version")?,
        created: field("created")?,
    };
    Ok((header, table))
}

/// Accepts the pairs schema versions this code reads and writes (a resumed version-1 dataset gets
/// version-1 shards).
fn check_schema_version(store: &dyn DatasetStore, header: &DatasetHeader) -> Result<()> {
    if pairs_schema_of(&header.schema_version).is_some() {
        return Ok(());
    }
    Err(Error::input(
        store.locate(DATASET_FILE),
        format!(
            "the dataset's schema is {}, this {CODE_VERSION} reads and writes {}: use a \
             matching pointreggpt, or build into a new output folder",
            header.schema_version,
            super::schema::PAIRS_VERSIONS.join(", ")
        ),
    ))
}

/// How many differing keys a config-mismatch message lists.
const MAX_LISTED_DIFFERENCES: usize = 10;

/// The refusal for a config whose hash differs from the dataset's, listing the differing keys.
fn config_mismatch(
    root: &Path,
    header: &DatasetHeader,
    recorded: &toml::Table,
    config: &toml::Table,
    config_hash: &str,
) -> Error {
    let short = |h: &str| h.chars().take(12).collect::<String>();
    let diffs = config_differences(recorded, config);
    let mut msg = format!(
        "the dataset {} was built with another pipeline config (its config_hash {}…, this run's {}…).",
        root.display(),
        short(&header.config_hash),
        short(config_hash)
    );
    if diffs.is_empty() {
        msg.push_str(" The keys and values are equal; only the hashes differ (computed by another code version?).");
    } else {
        msg.push_str(" Differing keys (dataset → this run):");
        for d in diffs.iter().take(MAX_LISTED_DIFFERENCES) {
            msg.push_str("\n  ");
            msg.push_str(d);
        }
        if diffs.len() > MAX_LISTED_DIFFERENCES {
            msg.push_str(&format!("\n  … and {} more", diffs.len() - MAX_LISTED_DIFFERENCES));
        }
    }
    msg.push_str(&format!(
        "\nA dataset holds the output of one config: write this run to a new output folder, or rerun with the \
         config recorded in {} to resume the dataset.",
        root.display().to_string().trim_end_matches('/').to_string() + "/" + DATASET_FILE
    ));
    Error::config("config", msg)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::atomic::{list_temps, TempName};
    use std::fs;
    use crate::shards::pairs::tests::sample_row;
    use crate::shards::row::PairRow;

    /// A small resolved config for the dataset tests.
    pub(crate) const CONFIG: &str = "seed = 7\n[voxel]\nsize = 0.025\n[overlap]\nradius = 0.0375\nmin = 0.3\n";

    /// Rows of units `units` (status = unit % 4) under config hash `h1`.
    pub(crate) fn rows(units: std::ops::Range<u64>) -> Vec<PairRow> {
        units.map(sample_row).map(|r| PairRow { config_hash: "h1".into(), ..r }).collect()
    }

    #[test]
    fn create_writes_the_layout_and_reopens() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("ds");
        let ds = Dataset::create_or_open(&root, CONFIG, "h1").unwrap();
        for d in [SHARDS_DIR, MANIFEST_DIR, TMP_DIR] {
            assert!(root.join(d).is_dir(), "{d}");
        }
        let text = fs::read_to_string(root.join(DATASET_FILE)).unwrap();
        let parsed: toml::Table = text.parse().unwrap();
        assert_eq!(parsed["dataset"]["config_hash"].as_str(), Some("h1"));
        assert_eq!(parsed["dataset"]["schema_version"].as_str(), Some(SCHEMA_VERSION));
        assert_eq!(parsed["voxel"]["size"].as_float(), Some(0.025));
        assert_eq!(parsed["seed"].as_integer(), Some(7), "top-level config keys stay top-level");
        assert_eq!(ds.header().code_version, CODE_VERSION);
        let again = Dataset::create_or_open(&root, CONFIG, "h1").unwrap();
        assert_eq!(again.header(), ds.header());
        assert_eq!(Dataset::open(&root).unwrap().header(), ds.header());
    }

    #[test]
    fn another_config_is_refused_naming_the_keys() {
        let dir = tempfile::tempdir().unwrap();
        Dataset::create_or_open(dir.path(), CONFIG, "h1").unwrap();
        let other = "seed = 8\n[voxel]\nsize = 0.025\n[overlap]\nradius = 0.05\n";
        let err = Dataset::create_or_open(dir.path(), other, "h2").unwrap_err();
        assert!(matches!(err, Error::Config { .. }));
        let msg = err.to_string();
        assert!(msg.contains("seed: 7 → 8"), "{msg}");
        assert!(msg.contains("overlap.radius: 0.0375 → 0.05"), "{msg}");
        assert!(msg.contains("overlap.min: 0.3 → (absent)"), "{msg}");
        assert!(!msg.contains("voxel.size"), "{msg}");
        assert!(msg.contains(&dir.path().display().to_string()) && msg.contains("new output folder"), "{msg}");
    }

    #[test]
    fn reserved_key_and_bad_toml_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let err = Dataset::create_or_open(dir.path(), "[dataset]\nx = 1\n", "h").unwrap_err();
        assert!(err.to_string().contains("dataset"), "{err}");
        assert!(Dataset::create_or_open(dir.path(), "seed = = 1", "h").is_err());
        assert!(!dir.path().join(DATASET_FILE).exists());
    }

    #[test]
    fn open_refuses_a_folder_that_is_not_a_dataset() {
        let dir = tempfile::tempdir().unwrap();
        let err = Dataset::open(dir.path()).unwrap_err().to_string();
        assert!(err.contains("not a pointreggpt dataset") && err.contains(&dir.path().display().to_string()), "{err}");
        fs::write(dir.path().join(DATASET_FILE), "seed = 1\n").unwrap();
        assert!(Dataset::open(dir.path()).unwrap_err().to_string().contains("[dataset]"));
    }

    #[test]
    fn racing_creators_all_succeed() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("new");
        let headers: Vec<DatasetHeader> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..8)
                .map(|_| s.spawn(|| Dataset::create_or_open(&root, CONFIG, "h1").map(|d| d.header().clone())))
                .collect();
            handles.into_iter().map(|h| h.join().unwrap().unwrap()).collect::<Vec<_>>()
        });
        let on_disk = Dataset::open(&root).unwrap().header().clone();
        assert!(headers.iter().all(|h| *h == on_disk), "every creator sees the one recorded header");
        assert!(list_temps(&root.join(TMP_DIR)).unwrap().is_empty());
    }

    #[test]
    fn stale_temps_are_cleaned_live_ones_kept() {
        let dir = tempfile::tempdir().unwrap();
        let ds = Dataset::create_or_open(dir.path(), CONFIG, "h1").unwrap();
        let mine = TempName::new("pairs-000001.parquet");
        let dead = TempName { pid: 4_194_304 + 99, ..mine.clone() };
        let init = TempName { pid: 1, ..mine.clone() };
        let foreign = TempName { host: "other-host".into(), ..dead.clone() };
        for n in [&mine, &dead, &init, &foreign] {
            fs::write(ds.tmp_dir().join(n.file_name()), b"x").unwrap();
        }
        let removed = ds.clean_stale_temps().unwrap();
        assert_eq!(removed, [ds.tmp_dir().join(dead.file_name())]);
        assert_eq!(list_temps(&ds.tmp_dir()).unwrap().len(), 3);
    }

    #[test]
    fn long_differences_are_cut_at_ten() {
        let old: toml::Table = (0..15).map(|i| format!("k{i:02} = {i}\n")).collect::<String>().parse().unwrap();
        let new = toml::Table::new();
        assert_eq!(config_differences(&old, &new).len(), 15);
        let header = DatasetHeader {
            config_hash: "a".into(),
            schema_version: SCHEMA_VERSION.into(),
            code_version: CODE_VERSION.into(),
            created: utc_now(),
        };
        let msg = config_mismatch(Path::new("/d"), &header, &old, &new, "b").to_string();
        assert!(msg.contains("k09: 9 → (absent)") && !msg.contains("k10:") && msg.contains("and 5 more"), "{msg}");
    }
}
