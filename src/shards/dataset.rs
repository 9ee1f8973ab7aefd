//! The dataset folder: `dataset.toml`, committed shards and their manifest entries, reading them back.
//!
//! See the module docs of [`crate::shards`] for the layout and the commit protocol.

use super::atomic::{hostname, list_temps, write_atomic, Publish, Published};
use super::manifest::{check_table_name, parse_shard_file_name, shard_stem, utc_now, ManifestEntry};
use super::pairs::{batch_to_pairs, pairs_to_batch};
use super::parquet_io::{read_parquet_file, write_parquet_bytes};
use super::row::PairRow;
use super::schema::{SCHEMA_VERSION, SCHEMA_VERSION_KEY};
use super::CODE_VERSION;
use crate::error::{Error, Result};
use arrow::array::RecordBatch;
use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

/// The file at the dataset's root holding the resolved config and the `[dataset]` header.
pub const DATASET_FILE: &str = "dataset.toml";
/// Folder of the committed shard files.
pub const SHARDS_DIR: &str = "shards";
/// Folder of the manifest entries.
pub const MANIFEST_DIR: &str = "manifest";
/// Folder of the files being written.
pub const TMP_DIR: &str = ".tmp";
/// The table of [`PairRow`]s.
pub const PAIRS_TABLE: &str = "pairs";

/// The `[dataset]` table of `dataset.toml`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DatasetHeader {
    /// blake3 of the resolved pipeline config, hex: every shard of the dataset was built with it.
    pub config_hash: String,
    /// Schema version of the pairs table (`pairs/1`).
    pub schema_version: String,
    /// Code version that created the dataset (each shard records its own in the manifest).
    pub code_version: String,
    /// UTC creation time, RFC 3339.
    pub created: String,
}

/// A dataset folder, opened for committing shards or for reading them.
#[derive(Clone, Debug)]
pub struct Dataset {
    root: PathBuf,
    header: DatasetHeader,
    worker: String,
}

impl Dataset {
    /// Opens the dataset at `root`, creating it (folders and `dataset.toml`) on first use.
    ///
    /// `resolved_config_toml` is the resolved pipeline config, stored verbatim below the `[dataset]`
    /// header; it may not have a top-level `dataset` key. When the dataset exists with another
    /// `config_hash`, this is refused with a message naming the differing config keys. Processes racing
    /// to create the same dataset with the same config all succeed.
    pub fn create_or_open(root: impl AsRef<Path>, resolved_config_toml: &str, config_hash: &str) -> Result<Dataset> {
        let root = root.as_ref().to_path_buf();
        if config_hash.is_empty() {
            return Err(Error::InvalidArgument("empty config hash".into()));
        }
        let config: toml::Table = resolved_config_toml
            .parse()
            .map_err(|e| Error::config("config", format!("the resolved config is not valid TOML: {e}")))?;
        if config.contains_key("dataset") {
            return Err(Error::config("dataset", "the top-level key `dataset` is reserved for the dataset header"));
        }
        for dir in [root.clone(), root.join(SHARDS_DIR), root.join(MANIFEST_DIR), root.join(TMP_DIR)] {
            fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
        }
        let path = root.join(DATASET_FILE);
        if !path.exists() {
            let header = DatasetHeader {
                config_hash: config_hash.to_string(),
                schema_version: SCHEMA_VERSION.to_string(),
                code_version: CODE_VERSION.to_string(),
                created: utc_now(),
            };
            let text = dataset_file_text(&header, resolved_config_toml);
            // Never replace: a racing creator may have published first; then compare with its file.
            if write_atomic(&root.join(TMP_DIR), &path, text.as_bytes(), Publish::KeepExisting)? == Published::Written {
                return Ok(Dataset::with_header(root, header));
            }
        }
        let (header, recorded) = read_dataset_file(&root)?;
        if header.config_hash != config_hash {
            return Err(config_mismatch(&root, &header, &recorded, &config, config_hash));
        }
        check_schema_version(&root, &header)?;
        Ok(Dataset::with_header(root, header))
    }

    /// Opens an existing dataset for reading (or committing with its recorded config).
    pub fn open(root: impl AsRef<Path>) -> Result<Dataset> {
        let root = root.as_ref().to_path_buf();
        let (header, _) = read_dataset_file(&root)?;
        check_schema_version(&root, &header)?;
        Ok(Dataset::with_header(root, header))
    }

    fn with_header(root: PathBuf, header: DatasetHeader) -> Dataset {
        Dataset { root, header, worker: format!("{}:{}", hostname(), std::process::id()) }
    }

    /// Sets the worker id recorded in manifest entries (default `<host>:<pid>`).
    pub fn with_worker(mut self, worker: impl Into<String>) -> Dataset {
        self.worker = worker.into();
        self
    }

    /// The dataset folder.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The `[dataset]` header of `dataset.toml`.
    pub fn header(&self) -> &DatasetHeader {
        &self.header
    }

    /// Where shard `shard` of `table` lives (committed or not).
    pub fn shard_path(&self, table: &str, shard: u64) -> PathBuf {
        self.root.join(SHARDS_DIR).join(format!("{}.parquet", shard_stem(table, shard)))
    }

    /// Where the manifest entry of shard `shard` of `table` lives.
    pub fn manifest_path(&self, table: &str, shard: u64) -> PathBuf {
        self.root.join(MANIFEST_DIR).join(format!("{}.json", shard_stem(table, shard)))
    }

    /// The folder of temporary files.
    pub fn tmp_dir(&self) -> PathBuf {
        self.root.join(TMP_DIR)
    }

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

    /// Withdraws the manifest entry of a shard (the shard then no longer exists for readers and a resume
    /// redoes it). Used by `verify --repair` on shards that fail verification.
    pub fn retract(&self, table: &str, shard: u64) -> Result<()> {
        check_table_name(table)?;
        let path = self.manifest_path(table, shard);
        match fs::remove_file(&path) {
            Ok(()) => super::atomic::sync_dir(&self.root.join(MANIFEST_DIR)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
            Err(e) => Err(Error::io(&path, e)),
        }
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

    /// Removes the temporary files left on this host by processes that no longer run; other live
    /// processes' (and other hosts') files stay. Returns the removed paths.
    pub fn clean_stale_temps(&self) -> Result<Vec<PathBuf>> {
        let mut removed = Vec::new();
        for (path, name) in list_temps(&self.tmp_dir())? {
            if name.is_some_and(|n| n.is_stale()) {
                match fs::remove_file(&path) {
                    Ok(()) => removed.push(path),
                    Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                    Err(e) => return Err(Error::io(&path, e)),
                }
            }
        }
        Ok(removed)
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

/// The header and the recorded config (without the `dataset` table) of the dataset at `root`.
fn read_dataset_file(root: &Path) -> Result<(DatasetHeader, toml::Table)> {
    let path = root.join(DATASET_FILE);
    let text = match fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(Error::input(root, format!("not a pointreggpt dataset: it has no {DATASET_FILE}")))
        }
        Err(e) => return Err(Error::io(&path, e)),
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

fn check_schema_version(root: &Path, header: &DatasetHeader) -> Result<()> {
    if header.schema_version == SCHEMA_VERSION {
        return Ok(());
    }
    Err(Error::input(
        root.join(DATASET_FILE),
        format!(
            "the dataset's schema is {}, this {CODE_VERSION} reads and writes {SCHEMA_VERSION}: use a matching \
             pointreggpt, or build into a new output folder",
            header.schema_version
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
        root.join(DATASET_FILE).display()
    ));
    Error::config("config", msg)
}

/// `key: old → new` for every dotted key whose value differs (`(absent)` for a missing key), sorted.
pub fn config_differences(old: &toml::Table, new: &toml::Table) -> Vec<String> {
    let (mut a, mut b) = (BTreeMap::new(), BTreeMap::new());
    flatten("", old, &mut a);
    flatten("", new, &mut b);
    let keys: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
    let show = |v: Option<&String>| match v {
        None => "(absent)".to_string(),
        Some(s) if s.chars().count() > 60 => format!("{}…", s.chars().take(60).collect::<String>()),
        Some(s) => s.clone(),
    };
    keys.into_iter()
        .filter(|k| a.get(*k) != b.get(*k))
        .map(|k| format!("{k}: {} → {}", show(a.get(k)), show(b.get(k))))
        .collect()
}

fn flatten(prefix: &str, table: &toml::Table, out: &mut BTreeMap<String, String>) {
    for (k, v) in table {
        let key = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
        match v {
            toml::Value::Table(t) => flatten(&key, t, out),
            other => {
                out.insert(key, other.to_string());
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shards::pairs::tests::sample_row;
    use crate::shards::row::Status;

    const CONFIG: &str = "seed = 7\n[voxel]\nsize = 0.025\n[overlap]\nradius = 0.0375\nmin = 0.3\n";

    fn rows(units: std::ops::Range<u64>) -> Vec<PairRow> {
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
    fn uncommitted_files_are_invisible() {
        let dir = tempfile::tempdir().unwrap();
        let ds = Dataset::create_or_open(dir.path(), CONFIG, "h1").unwrap();
        ds.commit_pairs(0, 0, 4, &rows(0..4)).unwrap();
        // A complete shard file without manifest entry (a crash between the two renames).
        let bytes =
            write_parquet_bytes(&crate::shards::pairs_schema(), &[pairs_to_batch(&rows(4..8)).unwrap()]).unwrap();
        fs::write(ds.shard_path(PAIRS_TABLE, 1), &bytes).unwrap();
        // A temp file of a shard being written.
        let tmp = ds.tmp_dir().join(super::super::atomic::TempName::new("pairs-000002.parquet").file_name());
        fs::write(&tmp, &bytes).unwrap();
        // An unreadable manifest entry.
        fs::write(ds.manifest_path(PAIRS_TABLE, 3), "{").unwrap();
        let units: Vec<u64> = ds.read_pairs().unwrap().iter().map(|r| r.unit_index).collect();
        assert_eq!(units, [0, 1, 2, 3]);
        assert_eq!(ds.committed(PAIRS_TABLE).unwrap().keys().copied().collect::<Vec<_>>(), [0]);
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

    #[test]
    fn stale_temps_are_cleaned_live_ones_kept() {
        let dir = tempfile::tempdir().unwrap();
        let ds = Dataset::create_or_open(dir.path(), CONFIG, "h1").unwrap();
        let mine = super::super::atomic::TempName::new("pairs-000001.parquet");
        let dead = super::super::atomic::TempName { pid: 4_194_304 + 99, ..mine.clone() };
        let init = super::super::atomic::TempName { pid: 1, ..mine.clone() };
        let foreign = super::super::atomic::TempName { host: "other-host".into(), ..dead.clone() };
        for n in [&mine, &dead, &init, &foreign] {
            fs::write(ds.tmp_dir().join(n.file_name()), b"x").unwrap();
        }
        let removed = ds.clean_stale_temps().unwrap();
        assert_eq!(removed, [ds.tmp_dir().join(dead.file_name())]);
        assert_eq!(list_temps(&ds.tmp_dir()).unwrap().len(), 3);
    }
}
