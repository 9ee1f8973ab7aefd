//! `pointreggpt export`: write a dataset's pairs in a layout registration trainers read.

use crate::error::{Error, Result};
use crate::export::geotransformer::CloudFormat;
use crate::export::{export, ExportOptions, Filter, Format};
use crate::shards::dataset::Dataset;
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
#[command(after_help = "--where takes a SQL boolean expression over the columns of the pairs table: the where clause of \
`pointreggpt query <dataset> \"select ... from pairs where <predicate>\"` (text quoted with ', names unquoted), e.g. \
--where \"status = 'ok' and overlap_source >= 0.3\", --where \"scene in ('a','b') and pair_key like '%#0'\", \
--where \"not (unit_index between 10 and 19)\", --where \"array_length(target_points) < 2000\". \
The pointreggpt and geotransformer formats take ok rows only; ply writes every matching row.")]
pub struct ExportArgs {
    /// The dataset: a folder, or an object-store URL (s3://bucket/prefix, gs://bucket/prefix, az://container/prefix).
    #[arg(value_parser = crate::commands::locations::dataset)]
    pub dataset: PathBuf,
    /// Output layout.
    #[arg(long, value_enum)]
    pub format: Format,
    /// Output folder (must not exist or be empty).
    #[arg(long, value_parser = crate::commands::locations::local_output)]
    pub out: PathBuf,
    /// Only rows where this SQL predicate is true, e.g. "status = 'ok' and overlap_source >= 0.3".
    #[arg(long = "where", value_name = "PREDICATE")]
    pub filter: Option<String>,
    /// Write at most N pairs.
    #[arg(long, value_name = "N")]
    pub limit: Option<usize>,
    /// geotransformer: the clouds' file format. pth = numpy arrays in torch.save's zip format, read by
    /// GeoTransformer's loader unmodified (torch.load(path, weights_only=False) on PyTorch >= 2.6, as for
    /// its own 3DMatch files); npy = np.load files.
    #[arg(long, value_enum, default_value = "pth")]
    pub cloud_format: CloudFormat,
    /// No progress bar.
    #[arg(long)]
    pub no_progress: bool,
}

pub fn run(args: &ExportArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    let filter = Filter::parse_opt(args.filter.as_deref())?;
    let ds = Dataset::open(&args.dataset)?;
    if args.cloud_format != CloudFormat::Pth && args.format != Format::Geotransformer {
        return Err(Error::config("--cloud-format", "only the geotransformer format has a cloud format"));
    }
    let opts = ExportOptions {
        format: args.format,
        out: args.out.clone(),
        filter,
        limit: args.limit,
        cloud_format: args.cloud_format,
        progress: !args.no_progress,
    };
    let r = export(&ds, &opts)?;
    let format = format!("{:?}", args.format).to_lowercase();
    let mut extra = Vec::new();
    if r.skipped > 0 {
        extra.push(format!("{} matching rows not ok, skipped", r.skipped));
    }
    if let Some(n) = r.gt_log_lines {
        extra.push(format!("{n} listed in metadata/gt.log by the official keep rule"));
    }
    if args.limit.is_some_and(|n| r.written as usize == n) {
        extra.push(format!("--limit {} reached", r.written));
    }
    let extra = if extra.is_empty() { String::new() } else { format!(" ({})", extra.join("; ")) };
    writeln!(out, "read {} rows, {} matched; wrote {} pairs ({format} format) to {}{extra}", r.rows_read, r.matched, r.written, args.out.display()).map_err(w)?;
    Ok(())
}
