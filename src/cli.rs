//! The command-line interface: clap structures and dispatch to one module per subcommand.

use crate::commands;
use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// Realistic training pairs for point-cloud registration from single depth maps (PointRegGPT).
#[derive(Debug, Parser)]
#[command(name = "pointreggpt", version, about, long_about = None)]
pub struct Cli {
    /// Worker threads for the numeric stages (default: all cores).
    #[arg(long, global = true, env = "POINTREGGPT_THREADS")]
    pub threads: Option<usize>,

    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Build a dataset of registration pairs from a pipeline config (resumable, shardable).
    Build(commands::build::BuildArgs),
    /// Fuse consecutive frames of a sequence (TSDF) and write the surface cloud and mesh as PLY.
    Fuse(commands::fuse::FuseArgs),
    /// A registration benchmark from posed sequences in the official 3DMatch layout: TSDF fragments
    /// (3DMatch / 3DLoMatch by overlap) or `--single-frames` pairs, with gt.log, gt.info, gt_overlap.log.
    Fragments(commands::fragments::FragmentsArgs),
    /// Build depth-correction training labels by TSDF fusion of sequences (resumable, shardable).
    Labels(commands::labels::LabelsArgs),
    /// Render a synthetic indoor scene, re-project one frame into a sampled pose, and write the two
    /// clouds (PLY), the depth maps (PNG) and the pose: the whole geometric path on embedded defaults.
    Demo(commands::demo::DemoArgs),
    /// Write a synthetic sequence (depth PNGs, camera-to-world poses, intrinsics) in the 3DMatch layout.
    Synth(commands::synth::SynthArgs),
    /// Run SQL over a dataset (tables pairs, labels, manifest; committed shards only) with DataFusion.
    Query(commands::query::QueryArgs),
    /// Check every committed shard of a dataset against its manifest entry (size, blake3, schema, rows).
    Verify(commands::verify::VerifyArgs),
    /// Bring the dataset's Delta Lake table (`_delta_log/`, for Delta readers such as deltalake, Polars or
    /// DuckDB) up to date with its committed shards; rebuilds the log from the manifest when it is missing.
    Publish(commands::publish::PublishArgs),
    /// List the sequences and frames found under a folder (3DMatch / 7-Scenes / SUN3D, TUM, ScanNet) with
    /// their intrinsics; `--check` also decodes every frame (depth PNG and pose) and reports the ones that fail.
    Inspect(commands::inspect::InspectArgs),
    /// Export pairs for trainers: the PointRegGPT authors' layout (gt.log), GeoTransformer's 3DMatch
    /// pickle + .pth clouds (`--cloud-format npy`: .npy), or PLY pairs; `--where` filters rows, `--limit`
    /// caps the count.
    Export(commands::export::ExportArgs),
    /// Write one PNG montage per pair: depth maps, condition with unknown pixels, known mask, inpainted
    /// target, and both clouds aligned by the stored pose.
    Preview(commands::preview::PreviewArgs),
    /// Rows by status (reject reasons) and overlap histograms, as stats.txt and a stats.png bar plot.
    Stats(commands::stats::StatsArgs),
    /// Train a network: `train correction` fits the depth-correction U-Net to label shards,
    /// `train diffusion` the diffusion denoiser to depth frames, `train descriptor` the registration patch
    /// descriptor to a dataset's pairs (checkpoints, resumable).
    Train(commands::train::TrainArgs),
    /// Evaluate: `eval correction` compares the handcrafted filters and U-Net checkpoints on held-out
    /// label shards; `eval inpaint` compares correction and fill methods with the depth captured on real
    /// sequences; `eval registration` scores a descriptor on a registration benchmark (FMR, IR, RR);
    /// `eval boost` trains the descriptor on several training sets and compares them on a benchmark.
    /// Tables and CSV.
    Eval(commands::eval::EvalArgs),
}

impl Cli {
    /// Runs the parsed command, writing human-readable output to `out`.
    pub fn run(&self, out: &mut dyn std::io::Write) -> crate::Result<()> {
        if let Some(n) = self.threads {
            if n == 0 {
                return Err(crate::Error::config("--threads", "must be at least 1"));
            }
            // Ignore the error of a second initialisation (tests may call run twice in one process).
            let _ = rayon::ThreadPoolBuilder::new().num_threads(n).build_global();
        }
        match &self.command {
            Command::Build(a) => commands::build::run(a, out),
            Command::Demo(a) => commands::demo::run(a, out),
            Command::Fuse(a) => commands::fuse::run(a, out),
            Command::Fragments(a) => commands::fragments::run(a, out),
            Command::Labels(a) => commands::labels::run(a, out),
            Command::Synth(a) => commands::synth::run(a, out),
            Command::Inspect(a) => commands::inspect::run(a, out),
            Command::Query(a) => commands::query::run(a, out),
            Command::Verify(a) => commands::verify::run(a, out),
            Command::Publish(a) => commands::publish::run(a, out),
            Command::Export(a) => commands::export::run(a, out),
            Command::Preview(a) => commands::preview::run(a, out),
            Command::Stats(a) => commands::stats::run(a, out),
            Command::Train(a) => commands::train::run(a, out),
            Command::Eval(a) => commands::eval::run(a, out),
        }
    }
}

/// Entry point of the binary: logging, parsing, running, and an exit code.
pub fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_env("POINTREGGPT_LOG").unwrap_or_else(|_| "warn".into()))
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let mut stdout = std::io::stdout().lock();
    match cli.run(&mut stdout) {
        Ok(()) => ExitCode::SUCCESS,
        Err(crate::Error::Interrupted) => {
            eprintln!("{}", crate::Error::Interrupted);
            ExitCode::from(130)
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
