//! Publishing: brings a dataset's Delta log up to date with its manifest, through the dataset's own
//! store ([`DatasetStore`]: a folder or an object store). Optimistic concurrency, as Delta writers do:
//! read the log, then the manifest, commit the difference as the next version with a create-only write
//! of `_delta_log/<version:020>.json`; a publisher that loses the race re-reads both and tries again.

use super::log::{commit_name, parse_commit, parse_commit_name, Action, TableState};
use super::reconcile::{check_table, metadata, plan, protocol};
use super::schema::schema_string;
use super::LOG_DIR;
use crate::atomic::Published;
use crate::error::{Error, Result};
use crate::shards::dataset::{Dataset, DATASET_FILE, PAIRS_TABLE};
use crate::shards::labels::LABELS_TABLE;
use crate::shards::manifest::ManifestEntry;
use crate::shards::schema::pairs_schema_of;
use crate::shards::store::DatasetStore;
use crate::shards::CODE_VERSION;
use std::collections::BTreeMap;
use std::fmt;
use std::time::Duration;

/// How many times a publisher tries to commit before giving up (each lost race costs one try; with N
/// publishers at once the last one commits within N tries).
const MAX_ATTEMPTS: u32 = 64;
/// The longest pause between two tries, milliseconds (pauses grow from 8 ms, with random jitter).
const MAX_BACKOFF_MS: u64 = 1000;

/// What [`publish`] did.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PublishReport {
    /// The table's version after publishing.
    pub version: u64,
    /// Whether this call committed that version (false: the table was already current).
    pub committed: bool,
    /// Shards added and files removed by this call's commit.
    pub added: usize,
    pub removed: usize,
    /// Commits lost to other publishers before this one's (or before finding the table current).
    pub conflicts: u32,
}

impl fmt::Display for PublishReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let lost = match self.conflicts {
            0 => String::new(),
            n => format!(" ({n} commits lost to other publishers first)"),
        };
        match self.committed {
            true => write!(f, "delta: committed version {} (+{} shards, -{} shards){lost}", self.version, self.added, self.removed),
            false => write!(f, "delta: table up to date at version {}{lost}", self.version),
        }
    }
}

/// Where a dataset's Delta log stands against its manifest.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LogStatus {
    /// The log's latest version.
    pub version: u64,
    /// Committed shards the log lacks (or holds with other bytes), and files it holds that are no longer committed.
    pub pending_adds: usize,
    pub pending_removes: usize,
}

/// Brings the Delta table of `ds` up to date with its committed `pairs` shards (creating the log at
/// version 0 if there is none): one new version holding every add and remove needed, or none when the
/// table is current. Safe to run from any number of processes at once.
pub fn publish(ds: &Dataset) -> Result<PublishReport> {
    let expected = metadata(ds.header(), table_schema(ds)?);
    let store = ds.store();
    let mut state = TableState::default();
    let mut rng = crate::rng::Rng::new(jitter_seed());
    for attempt in 0..MAX_ATTEMPTS {
        // The log first, then the manifest: a commit made from them undoes no change published before it.
        catch_up(store, &mut state)?;
        check_table(&state, &expected, &store.locate(LOG_DIR))?;
        let entries = committed_pairs(ds)?;
        let now = now_ms();
        let changes = plan(&state, &entries, now);
        if changes.is_empty() && state.version.is_some() {
            return Ok(PublishReport { version: state.next_version() - 1, committed: false, added: 0, removed: 0, conflicts: attempt });
        }
        let removed = changes.iter().filter(|a| matches!(a, Action::Remove(_))).count();
        let added = changes.len() - removed;
        let version = state.next_version();
        let mut actions = vec![commit_info(now, state.version, added, removed, &ds.worker)];
        if version == 0 {
            actions.extend([Action::Protocol(protocol()), Action::Metadata(expected.clone())]);
        }
        actions.extend(changes);
        let rel = format!("{LOG_DIR}/{}", commit_name(version));
        match store.create_text(&rel, &super::log::commit_text(&actions))? {
            Published::Written => return Ok(PublishReport { version, committed: true, added, removed, conflicts: attempt }),
            Published::AlreadyThere => {
                tracing::debug!("{}: another publisher committed it first; re-reading the log", store.locate(&rel).display());
                let cap = MAX_BACKOFF_MS.min(8 << attempt.min(7));
                std::thread::sleep(Duration::from_millis(rng.below(cap + 1)));
            }
        }
    }
    Err(Error::Store {
        url: store.locate(LOG_DIR).display().to_string(),
        message: format!("other publishers kept committing first ({MAX_ATTEMPTS} tries); run `pointreggpt publish` again"),
    })
}

/// The log's version and what a publish would change, `None` when the dataset has no Delta log.
pub fn status(ds: &Dataset) -> Result<Option<LogStatus>> {
    let mut state = TableState::default();
    catch_up(ds.store(), &mut state)?;
    let Some(version) = state.version else { return Ok(None) };
    let changes = plan(&state, &committed_pairs(ds)?, now_ms());
    let pending_removes = changes.iter().filter(|a| matches!(a, Action::Remove(_))).count();
    Ok(Some(LogStatus { version, pending_adds: changes.len() - pending_removes, pending_removes }))
}

/// The Delta schema of the dataset's pairs table; refuses datasets that are not (or cannot be) one.
fn table_schema(ds: &Dataset) -> Result<String> {
    let version = &ds.header().schema_version;
    let dataset_file = ds.store().locate(DATASET_FILE);
    let schema = pairs_schema_of(version).ok_or_else(|| Error::input(&dataset_file, format!("unknown pairs schema {version}")))?;
    let text = schema_string(&schema).map_err(|e| {
        Error::input(&dataset_file, format!("a {version} dataset cannot be published as a Delta table: {e}; build it into a new folder to get {}", crate::shards::SCHEMA_VERSION))
    })?;
    Ok(text)
}

/// The committed `pairs` shards; stops when an entry could not be fetched (it must not count as
/// withdrawn), and on a labels dataset (no pairs shards, labels shards).
fn committed_pairs(ds: &Dataset) -> Result<BTreeMap<u64, ManifestEntry>> {
    let scan = ds.scan_manifest()?;
    if let Some(first) = scan.read_errors.first() {
        return Err(Error::Store { url: ds.root().display().to_string(), message: format!("cannot read the manifest to publish it: {first}") });
    }
    let labels = scan.entries.keys().any(|(t, _)| t == LABELS_TABLE);
    let pairs: BTreeMap<u64, ManifestEntry> = scan.entries.into_iter().filter(|((t, _), _)| t == PAIRS_TABLE).map(|((_, s), e)| (s, e)).collect();
    if labels && pairs.is_empty() {
        return Err(Error::input(ds.root(), "a labels dataset: only `pairs` datasets are published as Delta tables"));
    }
    Ok(pairs)
}

/// Replays into `state` the commits of `_delta_log/` after its version.
fn catch_up(store: &dyn DatasetStore, state: &mut TableState) -> Result<()> {
    let mut versions: Vec<u64> = store
        .list(LOG_DIR)?
        .iter()
        .filter_map(|l| parse_commit_name(&l.name))
        .filter(|v| state.version.map_or(true, |cur| *v > cur))
        .collect();
    versions.sort_unstable();
    let rels: Vec<String> = versions.iter().map(|v| format!("{LOG_DIR}/{}", commit_name(*v))).collect();
    for ((version, rel), text) in versions.into_iter().zip(&rels).zip(store.read_texts(&rels)) {
        let location = store.locate(rel);
        let text = text?.ok_or_else(|| Error::input(&location, "listed, then gone: a Delta commit is never removed"))?;
        state.apply(version, parse_commit(&text, &location)?, &location)?;
    }
    Ok(())
}

/// The `commitInfo` of a publish (what `DESCRIBE HISTORY` and `DeltaTable.history()` show).
fn commit_info(now: i64, read_version: Option<u64>, added: usize, removed: usize, publisher: &str) -> Action {
    let mut info = serde_json::json!({
        "timestamp": now,
        "operation": if removed == 0 { "WRITE" } else { "DELETE" },
        "operationParameters": { "mode": "Append" },
        "engineInfo": CODE_VERSION,
        "isBlindAppend": removed == 0,
        "pointreggpt": { "publisher": publisher, "addedShards": added, "removedShards": removed },
    });
    if let Some(v) = read_version {
        info["readVersion"] = v.into();
    }
    Action::CommitInfo(info)
}

fn now_ms() -> i64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_millis() as i64).unwrap_or(0)
}

/// A seed that differs between publishers, so their retries spread out.
fn jitter_seed() -> u64 {
    static CALLS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let t = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos() as u64).unwrap_or(0);
    t ^ (u64::from(std::process::id()) << 32) ^ n.wrapping_mul(0x9E37_79B9_7F4A_7C15)
}
