//! `pointreggpt verify`: check every committed shard against its manifest entry and schema.

use crate::error::{Error, Result};
use crate::shards::dataset::Dataset;
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
#[command(after_help = "The dataset is a folder or an object-store URL (s3://bucket/prefix, gs://…, az://…).\n\
On an object store, --repair also aborts the multipart uploads of writers that died and removes the shard \
objects that no manifest entry names and no running writer is writing.")]
pub struct VerifyArgs {
    /// The dataset: a folder or an object-store URL.
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
        return Ok(());
    }
    if report.is_ok() {
        return Ok(());
    }
    Err(Error::input(&args.dataset, format!("{} problems found (listed above); `--repair` withdraws the bad shards so a resume redoes them", report.problems.len())))
}
