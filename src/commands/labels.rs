//! `pointreggpt labels`: build correction-network training labels by TSDF fusion of real sequences.

use super::build::{load_toml, worker_from_env};
use crate::error::{Error, Result};
use crate::labels::{run_labels, LabelsConfig};
use crate::pipeline::BuildOptions;
use crate::runtime::CancelToken;
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
#[command(after_help = "Each window of `window.frames` consecutive frames is fused (TSDF) in its reference camera's frame; \
the dense surface P_d and its voxel-downsampled copy P_s are re-projected into sampled poses as I_d and I_s, and \
labelled M_gt = |I_s - I_d| < tau_gt. Resumable and shardable exactly like `build`.")]
pub struct LabelsArgs {
    /// Label pipeline config (TOML), for example pipelines/labels-demo.toml.
    pub config: PathBuf,
    /// Dataset folder (default out/<config file stem>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Override a config value (repeatable), e.g. --set window.frames=30.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// This worker's index (default from the scheduler's environment, as `build`).
    #[arg(long)]
    pub worker: Option<u64>,
    /// Number of workers.
    #[arg(long)]
    pub workers: Option<u64>,
    /// Stop at the first bad input instead of recording an `input_error` row.
    #[arg(long)]
    pub strict: bool,
    /// No progress bars.
    #[arg(long)]
    pub no_progress: bool,
    /// Print the resolved config and exit.
    #[arg(long)]
    pub print_config: bool,
}

pub fn run(args: &LabelsArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    let config: LabelsConfig = load_toml(&args.config, &args.set)?;
    config.validate()?;
    if args.print_config {
        write!(out, "{}", config.to_toml()).map_err(w)?;
        return Ok(());
    }
    let (worker, workers) = worker_from_env(args.worker, args.workers)?;
    let dataset = args.out.clone().unwrap_or_else(|| PathBuf::from("out").join(args.config.file_stem().unwrap_or_default()));
    let opts = BuildOptions { out: dataset.clone(), worker, workers, strict: args.strict, progress: !args.no_progress };
    let cancel = CancelToken::new();
    cancel.cancel_on_signals();
    let r = run_labels(&config, &opts, &cancel)?;
    let by: Vec<String> = r.rows_by_status.iter().map(|(k, v)| format!("{k} {v}")).collect();
    writeln!(out, "label dataset {} (config {})", dataset.display(), &config.dataset_hash()[..12]).map_err(w)?;
    writeln!(out, "{} windows in {} shards; worker {worker} of {workers}: {} already committed, {} committed now", r.windows, r.total_shards, r.already_committed, r.committed_now.len()).map_err(w)?;
    writeln!(out, "rows written: {} ({})", r.rows_by_status.values().sum::<u64>(), if by.is_empty() { "none".into() } else { by.join(", ") }).map_err(w)?;
    writeln!(out, "time {:.1} s, {:.2} windows/s", r.summary.wall.as_secs_f64(), r.summary.rate()).map_err(w)?;
    write!(out, "{}", r.summary.stage_table()).map_err(w)?;
    writeln!(out, "shards: {}/shards/labels-*.parquet", dataset.display()).map_err(w)?;
    if r.summary.cancelled {
        return Err(Error::Interrupted);
    }
    Ok(())
}
