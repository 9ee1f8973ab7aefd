//! `pointreggpt preview`: one PNG montage per pair (depth maps, known mask, both clouds aligned).

use crate::error::{Error, Result};
use crate::export::Filter;
use crate::preview::{write_previews, PreviewOptions};
use crate::shards::dataset::Dataset;
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
#[command(after_help = "Each montage shows, left to right: the source depth, the re-projected condition (grey = unknown \
pixels), the known mask, the inpainted target (one Turbo depth scale per montage, black = no depth), and both clouds \
rendered into the target camera with the stored pose (red = source, green = target, yellow = both clouds at the pixel, their depths less than 5 cm apart). \
--where takes a SQL predicate over the pairs table, as `pointreggpt export` does, e.g. --where \"status = 'low_overlap' \
and scene like 'scene0%'\".")]
pub struct PreviewArgs {
    /// The dataset: a folder, or an object-store URL (s3://bucket/prefix, gs://bucket/prefix, az://container/prefix).
    #[arg(value_parser = crate::commands::locations::dataset)]
    pub dataset: PathBuf,
    /// Output folder (created); files are named <pair key, sanitized>.png.
    #[arg(long, value_parser = crate::commands::locations::local_output)]
    pub out: PathBuf,
    /// Only rows where this SQL predicate is true, e.g. "status = 'ok' and overlap_source < 0.3".
    #[arg(long = "where", value_name = "PREDICATE")]
    pub filter: Option<String>,
    /// At most N montages (the first matching rows in unit order).
    #[arg(long, value_name = "N", default_value_t = 8)]
    pub limit: usize,
    /// No progress bar.
    #[arg(long)]
    pub no_progress: bool,
}

pub fn run(args: &PreviewArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    let filter = Filter::parse_opt(args.filter.as_deref())?;
    let ds = Dataset::open(&args.dataset)?;
    let opts = PreviewOptions { out: args.out.clone(), filter, limit: args.limit, progress: !args.no_progress };
    let files = write_previews(&ds, &opts)?;
    writeln!(out, "wrote {} preview PNGs to {}", files.len(), args.out.display()).map_err(w)?;
    Ok(())
}
