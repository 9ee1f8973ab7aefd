//! `pointreggpt stats`: rows by status (reject reasons) and overlap histograms, as a table and a plot.

use crate::error::{Error, Result};
use crate::export::Filter;
use crate::preview::{collect_stats, write_stats};
use crate::shards::dataset::Dataset;
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct StatsArgs {
    /// The dataset folder.
    pub dataset: PathBuf,
    /// Output folder (created) for stats.txt and stats.png.
    #[arg(long)]
    pub out: PathBuf,
    /// Add tables per scene.
    #[arg(long)]
    pub per_scene: bool,
    /// Only rows matching this predicate (the language of `pointreggpt export --where`).
    #[arg(long = "where", value_name = "PREDICATE")]
    pub filter: Option<String>,
    /// No progress bar.
    #[arg(long)]
    pub no_progress: bool,
}

pub fn run(args: &StatsArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    let filter = Filter::parse_opt(args.filter.as_deref())?;
    let ds = Dataset::open(&args.dataset)?;
    let stats = collect_stats(&ds, &filter, !args.no_progress)?;
    let text = write_stats(&stats, &args.out, args.per_scene)?;
    write!(out, "{text}").map_err(w)?;
    writeln!(out, "\nwrote {0}/stats.txt and {0}/stats.png", args.out.display()).map_err(w)?;
    Ok(())
}
