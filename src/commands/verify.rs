//! `pointreggpt verify`: check every committed shard against its manifest entry and schema.

use crate::error::{Error, Result};
use crate::shards::dataset::Dataset;
use crate::shards::delta;
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
#[command(after_help = "The dataset is a folder or an object-store URL (s3://bucket/prefix, gs://…, az://…).\n\
On an object store, --repair also aborts the multipart uploads of writers that died and removes the shard \
objects that no manifest entry names and no running writer is writing.\n\
When the dataset has a Delta Lake table (_delta_log/), verify says whether it lists exactly the committed shards, \
and --repair publishes the withdrawals as a new table version.")]
pub struct VerifyArgs {
    /// The dataset: a folder or an object-store URL.
    #[arg(value_parser = crate::commands::locations::dataset)]
    pub dataset: PathBuf,
    /// Withdraw the manifest entries of shards that fail (the next build run redoes exactly those) and
    /// remove temporary files of dead processes (on an object store: their upload records, incomplete
    /// multipart uploads and uncommitted objects).
    #[arg(long)]
    pub repair: bool,
}

pub fn run(args: &VerifyArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    let ds = Dataset::open(&args.dataset)?;
    let report = ds.verify()?;
    writeln!(out, "{report}").map_err(w)?;
    if args.repair {
        let done = ds.repair(&report)?;
        writeln!(
            out,
            "repair: withdrew {} manifest entries (run the build again to redo them), removed {} stale temporary files \
             and {} uncommitted shard objects",
            done.retracted,
            done.cleaned.len(),
            done.orphans_removed.len()
        )
        .map_err(w)?;
        // The Delta table follows the manifest in the same run (only a dataset that has one).
        if delta::status(&ds)?.is_some() {
            writeln!(out, "{}", delta::publish(&ds)?).map_err(w)?;
        }
        return Ok(());
    }
    match delta::status(&ds)? {
        Some(s) if s.pending_adds + s.pending_removes > 0 => writeln!(
            out,
            "delta: version {} lacks {} committed shards and lists {} withdrawn ones (run `pointreggpt publish`)",
            s.version, s.pending_adds, s.pending_removes
        )
        .map_err(w)?,
        Some(s) => writeln!(out, "delta: version {} lists exactly the committed shards", s.version).map_err(w)?,
        None => {}
    }
    if report.is_ok() {
        return Ok(());
    }
    Err(Error::input(&args.dataset, format!("{} problems found (listed above); `--repair` withdraws the bad shards so a resume redoes them", report.problems.len())))
}
