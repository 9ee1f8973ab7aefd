//! `pointreggpt build`: turn depth frames into a dataset of registration pairs.

use crate::error::{Error, Result};
pub use crate::pipeline::load::load_toml;
use crate::pipeline::{run_build, BuildConfig, BuildOptions};
use crate::runtime::CancelToken;
use crate::shards::dataset::Dataset;
use crate::shards::delta::publish;
use std::io::Write;
use std::path::{Path, PathBuf};

#[derive(Debug, clap::Args)]
#[command(after_help = "Scale-out: run the same command as N workers (a Slurm job array, a Kubernetes Indexed Job, \
or by hand with --worker i --workers N) on one dataset folder or bucket prefix (--out s3://bucket/prefix); worker i \
builds the shards k with k mod N = i. An interrupted build resumes where it stopped when run again with the same config. \
On an object store (no rename) each shard is an immutable object under a unique name, committed by creating its \
manifest entry with a create-only put (schemas/store-protocol.md).")]
pub struct BuildArgs {
    /// Pipeline config (TOML), for example pipelines/demo.toml. Relative paths inside it (source folders,
    /// checkpoints) are relative to its folder; `builtin:models/<file>` names a model built into the binary.
    pub config: PathBuf,
    #[command(flatten)]
    pub run: RunArgs,
    /// Do not publish the committed shards to the dataset's Delta Lake table (`_delta_log/`) at the end
    /// (`pointreggpt publish` does it later).
    #[arg(long)]
    pub no_publish: bool,
    /// Frames kept decoded, resized and back-projected for their next samples (a frame's
    /// samples_per_frame samples are consecutive units), about 1 MB each; 0 decodes each unit's frame
    /// anew. The pairs are the same either way.
    #[arg(long, value_name = "FRAMES", default_value_t = BuildOptions::FRAME_CACHE)]
    pub frame_cache: usize,
    /// With a `scene` method: scenes kept fused for the next units of their block of source frames
    /// (each holds a TSDF volume, a few tens of MB at 1 cm voxels); 0 fuses a scene for every unit. The
    /// pairs are the same either way.
    #[arg(long, value_name = "SCENES", default_value_t = BuildOptions::SCENE_CACHE)]
    pub scene_cache: usize,
    /// Where the config's networks run (the correction U-Net, the diffusion model): cpu, cuda or cuda:N.
    /// Checked before any work: without that GPU (or with a CPU-only libtorch) the build stops at once.
    /// Needs a CUDA libtorch (LIBTORCH_USE_PYTORCH=1 with a CUDA PyTorch, docs/building.md); not run on a
    /// GPU in this project's tests (no GPU here). On the CPU the rows are the same whatever the threads.
    #[arg(long, default_value = "cpu")]
    pub device: String,
}

/// The flags `build` and `labels` share: where the dataset goes, overrides, the worker split.
#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Dataset folder or object-store URL (s3://bucket/prefix, gs://bucket/prefix, az://container/prefix;
    /// credentials and endpoint from the usual AWS_*, GOOGLE_*, AZURE_* variables or ~/.aws profile);
    /// created, or resumed when it holds a dataset with the same config. Default: out/<config file stem>.
    #[arg(long, value_parser = crate::commands::locations::dataset)]
    pub out: Option<PathBuf>,
    /// Override a config value (repeatable), e.g. --set voxelize.voxel=0.03 --set source.path=/data/3dmatch.
    /// A relative path given here is relative to the working directory.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// This worker's index, 0-based. Default: $SLURM_ARRAY_TASK_ID (minus $SLURM_ARRAY_TASK_MIN),
    /// $JOB_COMPLETION_INDEX, $AWS_BATCH_JOB_ARRAY_INDEX, else 0.
    #[arg(long)]
    pub worker: Option<u64>,
    /// Number of workers. Default: $SLURM_ARRAY_TASK_COUNT, $POINTREGGPT_WORKERS, else 1.
    #[arg(long)]
    pub workers: Option<u64>,
    /// Stop at the first bad input frame instead of recording it as an `input_error` row.
    #[arg(long)]
    pub strict: bool,
    /// No progress bars.
    #[arg(long)]
    pub no_progress: bool,
    /// Print the resolved config (every default filled in) and exit.
    #[arg(long)]
    pub print_config: bool,
}

impl RunArgs {
    /// The run options for `config` (the dataset folder defaults to out/<config file stem>).
    pub fn options(&self, config: &Path) -> Result<BuildOptions> {
        let (worker, workers) = worker_from_env(self.worker, self.workers)?;
        let out = self.out.clone().unwrap_or_else(|| PathBuf::from("out").join(config.file_stem().unwrap_or_default()));
        Ok(BuildOptions { worker, workers, strict: self.strict, progress: !self.no_progress, ..BuildOptions::into_folder(out) })
    }
}

/// Reads and validates a build config.
pub fn load_config(path: &Path, set: &[String]) -> Result<BuildConfig> {
    let config: BuildConfig = load_toml(path, set)?;
    config.validate()?;
    Ok(config)
}

/// The worker index and count from the flags or the scheduler's environment.
pub fn worker_from_env(worker: Option<u64>, workers: Option<u64>) -> Result<(u64, u64)> {
    let env = |k: &str| -> Result<Option<u64>> {
        match std::env::var(k) {
            Ok(v) if !v.trim().is_empty() => v.trim().parse().map(Some).map_err(|_| Error::config(k, format!("`{v}` is not a non-negative integer"))),
            _ => Ok(None),
        }
    };
    let worker = match worker {
        Some(w) => w,
        None => match env("SLURM_ARRAY_TASK_ID")? {
            Some(id) => id.checked_sub(env("SLURM_ARRAY_TASK_MIN")?.unwrap_or(0)).ok_or_else(|| Error::config("SLURM_ARRAY_TASK_ID", "is below SLURM_ARRAY_TASK_MIN"))?,
            None => env("JOB_COMPLETION_INDEX")?.or(env("AWS_BATCH_JOB_ARRAY_INDEX")?).unwrap_or(0),
        },
    };
    let workers = match workers {
        Some(n) => n,
        None => env("SLURM_ARRAY_TASK_COUNT")?.or(env("POINTREGGPT_WORKERS")?).unwrap_or(1),
    };
    Ok((worker, workers))
}

pub fn run(args: &BuildArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    let device = crate::nn::parse_device(&args.device)?;
    let config = load_config(&args.config, &args.run.set)?;
    if args.run.print_config {
        write!(out, "{}", config.to_toml()).map_err(w)?;
        return Ok(());
    }
    let opts = BuildOptions { frame_cache: args.frame_cache, scene_cache: args.scene_cache, device, ..args.run.options(&args.config)? };
    let (dataset, worker, workers) = (opts.out.clone(), opts.worker, opts.workers);
    let cancel = CancelToken::new();
    cancel.cancel_on_signals();
    let r = run_build(&config, &opts, &cancel)?;

    let rows: u64 = r.rows_by_status.values().sum();
    writeln!(out, "dataset {} (config {})", dataset.display(), &r.config_hash[..12]).map_err(w)?;
    writeln!(
        out,
        "{} units in {} shards; worker {worker} of {workers}: {} shards already committed, {} committed now{}",
        r.total_units,
        r.total_shards,
        r.already_committed,
        r.committed_now.len(),
        if r.summary.cancelled { " (interrupted: run the same command again to resume)" } else { "" }
    )
    .map_err(w)?;
    let by: Vec<String> = r.rows_by_status.iter().map(|(k, v)| format!("{k} {v}")).collect();
    writeln!(out, "rows written: {rows} ({})", if by.is_empty() { "none".into() } else { by.join(", ") }).map_err(w)?;
    let scenes = if config.uses_scene() { format!("; scenes fused {}", r.scenes_fused) } else { String::new() };
    writeln!(out, "time {:.1} s, {:.1} pairs/s; frames decoded {} times{scenes}", r.summary.wall.as_secs_f64(), r.summary.rate(), r.frames_prepared)
        .map_err(w)?;
    write!(out, "{}", r.summary.stage_table()).map_err(w)?;
    writeln!(out, "committed shards: listed in {}/manifest/", dataset.display()).map_err(w)?;
    writeln!(
        out,
        "query it, e.g.: pointreggpt query {} \"select status, count(*) n, avg(overlap_source) ov from pairs group by status\"",
        dataset.display()
    )
    .map_err(w)?;
    if r.summary.cancelled {
        return Err(Error::Interrupted);
    }
    if !args.no_publish {
        publish_table(&dataset, out)?;
    }
    Ok(())
}

/// Publishes the committed shards to the dataset's Delta table (a version-1 dataset has none: said so).
fn publish_table(dataset: &Path, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    let ds = Dataset::open(dataset)?;
    if ds.header().schema_version == crate::shards::SCHEMA_VERSION_1 {
        writeln!(out, "delta: not published: a {} dataset has unsigned integers, which Delta cannot type", ds.header().schema_version).map_err(w)?;
        return Ok(());
    }
    let report = publish(&ds).map_err(|e| {
        Error::Store { url: dataset.display().to_string(), message: format!("the shards are committed, but publishing the Delta table failed: {e}; run `pointreggpt publish {}`", dataset.display()) }
    })?;
    writeln!(out, "{report}: the dataset is a Delta Lake table, e.g.").map_err(w)?;
    writeln!(out, "  python3 -c \"import polars as pl; print(pl.read_delta('{}').group_by('status').len())\"", dataset.display()).map_err(w)
}
