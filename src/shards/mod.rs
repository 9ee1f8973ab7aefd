//! Shards: the Arrow schemas, zstd Parquet files, the commit protocol and the manifest of a dataset.
//!
//! # Dataset layout
//!
//! ```text
//! <root>/dataset.toml                           resolved pipeline config under a [dataset] header
//!                                               (config_hash, schema_version, code_version, created)
//! <root>/shards/<table>-<shard:06>.parquet      one shard: the rows of a fixed range of work units
//! <root>/manifest/<table>-<shard:06>.json       one entry per committed shard (ManifestEntry)
//! <root>/.tmp/<host>~<pid>~<target>~<nonce>.tmp files being written
//! <root>/_delta_log/<version:020>.json          the Delta Lake table over the committed pairs shards
//!                                               ([`delta`]: a view of the manifest that publishing keeps current)
//! ```
//!
//! Tables: `pairs` ([`PairRow`], schema `pairs/3`, `schemas/pairs-v3.md`; version-1 and version-2 datasets
//! are read and resumed through [`pairs_versions`]) and any other table a module
//! brings as a [`RecordBatch`](arrow::array::RecordBatch) (`labels`), committed with
//! [`Dataset::commit_shard`].
//!
//! # Commit protocol
//!
//! A shard is a fixed range of work units, so whichever worker builds it, it holds the same rows.
//! Committing it ([`Dataset::commit_shard`]):
//! 1. encode the batch as Parquet (zstd) and write it to a temporary file in `.tmp/`, fsync it;
//! 2. publish it as `shards/<table>-<shard>.parquet` without replacing an existing file (hard link; a
//!    file already there from another committer is adopted if it decodes with the same schema and row
//!    count, else replaced), fsync `shards/`;
//! 3. write the manifest entry (row counts, size and blake3 of the published file, config hash, code
//!    version, worker, time) the same way: temporary file, fsync, rename into `manifest/`, fsync.
//!
//! On an object store (`s3://`, `gs://`, `az://`; [`store`]) nothing can be renamed: each write of a shard
//! is an immutable object under a unique name (`shards/<table>-<shard:06>-<id>.parquet`), committed by
//! creating its manifest entry with a create-only put; the loser of a race deletes its object
//! (`schemas/store-protocol.md`, [`store::object_commit`]). The rest of the code reaches the files only
//! through [`store::DatasetStore`].
//!
//! Only shards with a manifest entry exist, for readers ([`Dataset::read_pairs`]) and for resume
//! ([`Dataset::committed`]): a crash at any point leaves either a committed shard or nothing visible (an
//! orphan shard file or a temporary file, which [`Dataset::verify`] lists and a resume redoes). Because a
//! published shard file is never replaced by a valid one, the manifest entry always describes the file in
//! place, however many workers commit the same shard concurrently. `dataset.toml` is created the same way
//! on first use; a run whose config hash differs from the recorded one is refused, naming the differing
//! config keys ([`Dataset::create_or_open`]).

pub mod commit;
pub mod config_diff;
pub mod dataset;
pub mod delta;
pub mod labels;
pub mod manifest;
pub mod pairs;
pub mod pairs_versions;
pub mod plan;
pub mod read;
pub mod parquet_io;
pub mod row;
pub mod schema;
pub mod store;
pub mod verify;

pub use dataset::{Dataset, DatasetHeader, PAIRS_TABLE};
pub use labels::{batch_to_labels, labels_schema, labels_to_batch, LabelRow, LABELS_TABLE};
pub use manifest::ManifestEntry;
pub use pairs::{batch_to_pairs, pairs_to_batch};
pub use parquet_io::{read_parquet_bytes, read_parquet_file, write_parquet_bytes, ROW_GROUP_ROWS};
pub use row::{PairRow, StageTiming, Status};
pub use schema::{pairs_schema, pairs_schema_of, PAIRS_VERSIONS, SCHEMA_VERSION, SCHEMA_VERSION_1, SCHEMA_VERSION_2, SCHEMA_VERSION_KEY};
pub use verify::{Problem, RepairReport, VerifyReport};

/// The code version recorded in rows, manifest entries and `dataset.toml`.
pub const CODE_VERSION: &str = concat!("pointreggpt ", env!("CARGO_PKG_VERSION"));
