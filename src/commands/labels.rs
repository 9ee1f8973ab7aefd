//! `pointreggpt labels`: build correction-network training labels by TSDF fusion of real sequences.

use super::build::{load_toml, RunArgs};
use crate::error::{Error, Result};
use crate::labels::{run_labels, LabelsConfig};
use crate::runtime::CancelToken;
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
#[command(after_help = "Each window of `window.frames` consecutive frames is fused (TSDF) in its reference camera's frame; \
the dense surface P_d and its voxel-downsampled copy P_s are re-projected into sampled poses as I_d and I_s, and \
labelled M_gt = |I_s - I_d| < tau_gt. Resumable and shardable exactly like `build`.")]
pub struct LabelsArgs {
    /// Label pipeline config (TOML), for example pipelines/labels-demo.toml. Relative paths inside it are
    /// relative to its folder.
    pub config: PathBuf,
    #[command(flatten)]
    pub run: RunArgs,
}

pub fn run(args: &LabelsArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    let config: LabelsConfig = load_toml(&args.config, &args.run.set)?;
    config.validate()?;
    if args.run.print_config {
        write!(out, "{}", config.to_toml()).map_err(w)?;
        return Ok(());
    }
    let opts = args.run.options(&args.config)?;
    let (dataset, worker, workers) = (opts.out.clone(), opts.worker, opts.workers);
    let cancel = CancelToken::new();
    cancel.cancel_on_signals();
    let r = run_labels(&config, &opts, &cancel)?;
    let by: Vec<String> = r.rows_by_status.iter().map(|(k, v)| format!("{k} {v}")).collect();
    writeln!(out, "label dataset {} (config {})", dataset.display(), &r.config_hash[..12]).map_err(w)?;
    writeln!(out, "{} windows in {} shards; worker {worker} of {workers}: {} already committed, {} committed now", r.windows, r.total_shards, r.already_committed, r.committed_now.len()).map_err(w)?;
    writeln!(out, "rows written: {} ({})", r.rows_by_status.values().sum::<u64>(), if by.is_empty() { "none".into() } else { by.join(", ") }).map_err(w)?;
    if r.unposed.frames > 0 {
        writeln!(out, "{} frame(s) without a camera pose left out of their windows; {} window(s) without any posed frame dropped", r.unposed.frames, r.unposed.windows).map_err(w)?;
    }
    writeln!(out, "time {:.1} s, {:.2} windows/s", r.summary.wall.as_secs_f64(), r.summary.rate()).map_err(w)?;
    write!(out, "{}", r.summary.stage_table()).map_err(w)?;
    writeln!(out, "shards: {}/shards/labels-*.parquet (those listed in {}/manifest/)", dataset.display(), dataset.display()).map_err(w)?;
    if r.summary.cancelled {
        return Err(Error::Interrupted);
    }
    Ok(())
}
