//! `pointreggpt publish`: bring the dataset's Delta Lake table (`_delta_log/`) up to date with its manifest.

use crate::error::{Error, Result};
use crate::shards::dataset::Dataset;
use crate::shards::delta::{publish, LOG_DIR};
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
#[command(after_help = "The dataset's root is a Delta Lake table: its _delta_log/ lists the committed pairs shards. \
Each build worker publishes at its end and verify --repair publishes the shards it withdraws; run this command to \
catch up by hand (a worker killed before its end), or to rebuild the log from the manifest after deleting _delta_log/. \
Idempotent, and safe to run from several processes at once.\n\n\
Read it with, e.g.:\n  \
python3 -c \"import polars as pl; print(pl.read_delta('out/demo').group_by('status').len())\"\n  \
python3 -c \"from deltalake import DeltaTable; print(DeltaTable('out/demo').to_pyarrow_table().num_rows)\"")]
pub struct PublishArgs {
    /// The dataset: a folder or an object-store URL (s3://bucket/prefix, gs://…, az://…).
    #[arg(value_parser = crate::commands::locations::dataset)]
    pub dataset: PathBuf,
}

pub fn run(args: &PublishArgs, out: &mut dyn Write) -> Result<()> {
    let ds = Dataset::open(&args.dataset)?;
    let report = publish(&ds)?;
    writeln!(out, "{report} in {}", ds.store().locate(LOG_DIR).display()).map_err(|e| Error::io("<stdout>", e))
}
