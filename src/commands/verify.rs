//! `pointreggpt verify`: check every committed shard against its manifest entry and schema.

use crate::error::{Error, Result};
use crate::shards::dataset::Dataset;
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct VerifyArgs {
    /// The dataset folder.
    pub dataset: PathBuf,
    /// Withdraw the manifest entries of shards that fail (the next build run redoes exactly those) and
    /// remove temporary files of dead processes.
    #[arg(long)]
    pub repair: bool,
}

pub fn run(args: &VerifyArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    let ds = Dataset::open(&args.dataset)?;
    let report = ds.verify()?;
    writeln!(out, "{report}").map_err(w)?;
    if report.is_ok() {
        return Ok(());
    }
    if args.repair {
        let mut retracted = 0;
        for p in &report.problems {
            if let Some((table, shard)) = &p.shard {
                ds.retract(table, *shard)?;
                retracted += 1;
            }
        }
        let cleaned = ds.clean_stale_temps()?.len();
        writeln!(out, "repair: withdrew {retracted} manifest entries (run the build again to redo them), removed {cleaned} stale temporary files").map_err(w)?;
        return Ok(());
    }
    Err(Error::input(&args.dataset, format!("{} problems found (listed above); `--repair` withdraws the bad shards so a resume redoes them", report.problems.len())))
}
