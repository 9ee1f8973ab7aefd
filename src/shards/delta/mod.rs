//! A Delta Lake table over the committed `pairs` shards, in `<dataset>/_delta_log/`: the dataset's root
//! is the table's root and each committed shard file (`shards/pairs-000042.parquet`, or its unique object
//! on a store) is one data file. Delta readers read it natively (the `deltalake` package, and Polars and
//! DuckDB through it, are tested; Spark, Trino and Databricks are not), and see only committed shards (a
//! `*.parquet` glob also reads withdrawn or uncommitted files).
//!
//! # The manifest stays the truth; the log is a view of it
//!
//! The build's commit protocol is unchanged (a shard exists when its manifest entry does). Publishing
//! ([`publish()`]) brings the log up to date with the manifest: one new Delta version holding an `add` for
//! every committed shard the table lacks (path relative to the root, size, the entry's commit time,
//! `stats` with `numRecords`, tags `shard` and `blake3`), and a `remove` for every file of the table that
//! no manifest entry names any more (a shard that `verify --repair` withdrew). Version 0 also holds the
//! `protocol` (reader 1, writer 2: no table features) and the `metaData` (schema derived from the Arrow
//! schema, [`schema`]; an id derived from the dataset, so a log rebuilt from the manifest is the same
//! table). Publishing a current table writes nothing.
//!
//! # Who publishes, and when
//!
//! - **Each build worker, at its end** (`pointreggpt build`, unless `--no-publish`; not after an
//!   interrupt): it publishes every committed shard, its own and the other workers', so the table is
//!   complete once the last worker ends.
//! - **`verify --repair`**, after withdrawing bad shards, when the dataset has a log: the withdrawn shards
//!   leave the table in the same run. (A dataset without a log gets none from `verify`.)
//! - **`pointreggpt publish <dataset>`** catches up by hand, e.g. after a worker was killed before its
//!   end, or rebuilds the log from the manifest after `_delta_log/` was deleted.
//!
//! # Exactly once, and concurrent publishers
//!
//! Exactly-once comes from comparing states, not from counting: a publisher replays the log, *then*
//! reads the manifest, and commits only the difference ([`reconcile::plan`]). The commit is the
//! create-only write of `_delta_log/<version:020>.json` through the dataset's store (a folder: temporary
//! file then hard link, which never replaces; an object store: a put with `If-None-Match: *`), so of N
//! publishers trying version v one wins; the others re-read the log from v and the manifest, recompute
//! the difference (now smaller or empty) and try v+1, after a short random pause. A shard is therefore
//! added once however many workers publish it, and because every attempt reads the manifest after the
//! log, no commit re-adds a shard withdrawn by a version it has already read, nor removes one added by it.
//! Delta's `txn` application ids are not needed: removes and rebuilds need the state comparison anyway.
//!
//! # What is not written
//!
//! No checkpoint (`*.checkpoint.parquet`, `_last_checkpoint`): readers replay the JSON commits, which for
//! the few versions a dataset gets (one per worker run and repair) costs milliseconds. Delta `VACUUM` is
//! never run: a removed shard file stays readable by older versions in a folder; on an object store
//! `verify --repair` deletes a withdrawn shard's object as it always did, so versions from before the
//! withdrawal list a file that is gone. Engines must not write to the table (OPTIMIZE, DELETE, ...):
//! the next publish would undo their change to match the manifest.

pub mod log;
pub mod publish;
pub mod reconcile;
pub mod schema;

pub use publish::{publish, status, LogStatus, PublishReport};

/// The Delta log's folder under the dataset's root.
pub const LOG_DIR: &str = "_delta_log";
