//! `pointreggpt stats`: rows by status (reject reasons) and overlap histograms, as a table and a plot.

use crate::error::{Error, Result};
use crate::export::Filter;
use crate::preview::{collect_stats, write_stats};
use crate::shards::dataset::Dataset;
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
#[command(after_help = "The counts come from one SQL aggregate over the committed shards (no row is decoded); \
--where is a SQL predicate over the pairs table, as for `pointreggpt export`, e.g. \
--where \"scene in ('a','b') and array_length(target_points) >= 2000\".")]
pub struct StatsArgs {
    /// The dataset: a folder, or an object-store URL (s3://bucket/prefix, gs://bucket/prefix, az://container/prefix).
    #[arg(value_parser = crate::commands::locations::dataset)]
    pub dataset: PathBuf,
    /// Output folder (created) for stats.txt and stats.png.
    #[arg(long, value_parser = crate::commands::locations::local_output)]
    pub out: PathBuf,
    /// Add tables per scene.
    #[arg(long)]
    pub per_scene: bool,
    /// Only rows where this SQL predicate is true (as `pointreggpt export --where`).
    #[arg(long = "where", value_name = "PREDICATE")]
    pub filter: Option<String>,
    /// Accepted like export's and preview's; stats draws no bar (it runs one SQL query).
    #[arg(long)]
    pub no_progress: bool,
}

pub fn run(args: &StatsArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    let filter = Filter::parse_opt(args.filter.as_deref())?;
    let ds = Dataset::open(&args.dataset)?;
    let stats = collect_stats(&ds, &filter)?;
    let text = write_stats(&stats, &args.out, args.per_scene)?;
    write!(out, "{text}").map_err(w)?;
    writeln!(out, "\nwrote {0}/stats.txt and {0}/stats.png", args.out.display()).map_err(w)?;
    Ok(())
}
