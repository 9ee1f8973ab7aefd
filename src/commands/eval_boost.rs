//! `pointreggpt eval boost`: the boost protocol of issue 16 in one resumable command (the work is in
//! [`crate::training::boost`]).

use super::build::load_config;
use crate::error::{Error, Result};
use crate::registration::EvalConfig;
use crate::training::boost::conditions::parse_list;
use crate::training::boost::{run_boost, BoostConfig};
use super::train_descriptor::DescriptorModelArgs;
use crate::training::descriptor::train::DescriptorTrainOptions;
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
#[command(
    after_help = "Conditions: C0 raw FPFH (no training); C1 real single-frame pairs (f, f+g) of the training frames with their \
captured poses (g in --real-gaps, both frames in the range, overlap >= 10 %), subsampled so that their overlap histogram (10 % bins) \
matches C3's, --pairs of them or as many as the scarcest bin allows (data-notes.txt says which); C2 re-projection only (no \
correction, no fill); C3 the classical generator (--classical-config: min-pool + background fill); C4 the neural generator \
(U-Net correction + the hole-aware diffusion refiner, 1 step from push-pull, checkpoints in --models); C5 = C1 + C3 and C6 = \
C1 + C4 at C1's pair count (half each); C5x2 / C6x2 at double (all of C1 + as many generated). Generated pairs are built \
in-process from the training frames with the build pipeline into <out>/data/<generator>/ (--pairs of them, drawn from \
ceil(1.25 * pairs / frames) views per frame). Each condition x seed trains the descriptor (--model, --steps) into \
<out>/<condition>/seed-<k>/ and is scored on every pair of the benchmark folder with the same sampling and RANSAC seeds \
(--eval-seed). A unit is skipped when its scores on this benchmark folder and these evaluation settings exist \
(scores-<key>.tsv): rerun the same command to resume; a run on another benchmark (or --only, --samples, --eval-seed) \
with the same --out scores the trained units again without retraining them; other training settings (--pairs, --steps, \
the model, the frames, the real gaps, the configs) with the same --out are refused (<out>/boost-settings.json records them). Writes <out>/boost.txt (the \
table: FMR / IR / RR mean [min-max] over seeds per condition, benchmark and sample count, and the paired IR differences C1-C0, \
C3-C0, C3-C2, C4-C3, C5-C1, C5x2-C1, C6-C1, C6x2-C1 with 95 % CIs over pairs x seeds and over the seeds' mean differences, \
the one to read when comparing training conditions: a training run moves all its pairs together; with --redraw it also covers the draw), boost.csv and boost-paired.csv."
)]
pub struct EvalBoostArgs {
    /// Evaluation benchmark folder (`pointreggpt fragments`, e.g. --single-frames of held-out frames).
    pub bench: PathBuf,
    /// The posed training sequence (one sequence folder, any layout `fragments` reads).
    #[arg(long)]
    pub sequence: PathBuf,
    /// First training frame.
    #[arg(long, default_value_t = 0)]
    pub first: usize,
    /// Training frames from --first on (both frames of every real pair, and every generated pair's source, lie in them).
    #[arg(long, default_value_t = 200)]
    pub frames: usize,
    /// Conditions, comma-separated (C0,C1,C2,C3,C4,C5,C5x2,C6,C6x2; default all).
    #[arg(long, value_delimiter = ',')]
    pub conditions: Vec<String>,
    /// Training seeds per condition.
    #[arg(long, default_value_t = 3)]
    pub seeds: u64,
    /// Each training seed k > 0 also draws its own training pairs (real and generated, from the same pools;
    /// units in `seed-<k>-redrawn/`), so the spread and the paired intervals cover the draw of the training
    /// set, not only the network's seed. Seed 0 keeps the protocol's draw.
    #[arg(long)]
    pub redraw: bool,
    /// Training pairs per condition (2000 for the full protocol, 500 for a quick one).
    #[arg(long, default_value_t = 2000)]
    pub pairs: usize,
    /// Descriptor training steps per unit (4 pairs x 64 points each).
    #[arg(long, default_value_t = 800)]
    pub steps: u64,
    /// The descriptor every unit trains (the patch network by default).
    #[command(flatten)]
    pub model: DescriptorModelArgs,
    /// Points sampled from each evaluation cloud, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "5000,1000,250")]
    pub samples: Vec<usize>,
    /// Only these benchmarks of the folder (comma-separated names).
    #[arg(long, value_delimiter = ',')]
    pub only: Vec<String>,
    /// Real pairs: a source frame every this many frames.
    #[arg(long, default_value_t = 2)]
    pub real_every: usize,
    /// Real pairs: gaps in frames between the two frames, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "5,10,15,20,25,30,40,50,60,70,80,90,100,120,140")]
    pub real_gaps: Vec<usize>,
    /// The classical generator's pipeline config (its source and frame selection are replaced).
    #[arg(long, default_value = "pipelines/paper-3dmatch-classical.toml")]
    pub classical_config: PathBuf,
    /// Folder holding correction-tiny.safetensors and diffusion-tiny-holes.safetensors (C4, C6).
    #[arg(long, default_value = "models")]
    pub models: PathBuf,
    /// Seed of the evaluation's point sampling and RANSAC (the same for every condition).
    #[arg(long, default_value_t = 0)]
    pub eval_seed: u64,
    /// Output folder (datasets, checkpoints, scores, tables).
    #[arg(long)]
    pub out: PathBuf,
    /// No progress bars.
    #[arg(long)]
    pub quiet: bool,
    /// libtorch intra-op threads.
    #[arg(long, default_value_t = 1)]
    pub torch_threads: i32,
}

pub fn run(a: &EvalBoostArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    if a.samples.is_empty() || a.samples.contains(&0) {
        return Err(Error::config("--samples", "must be positive counts, e.g. 5000,1000,250"));
    }
    if a.real_every == 0 || a.real_gaps.is_empty() || a.real_gaps.contains(&0) {
        return Err(Error::config("--real-every/--real-gaps", "must be positive"));
    }
    crate::nn::set_torch_threads(a.torch_threads)?;
    let mut train = DescriptorTrainOptions::new(a.out.clone());
    train.steps = a.steps;
    train.model = a.model.model()?;
    train.checkpoint_every = (a.steps / 4).clamp(1, 100);
    train.validate()?;
    let cfg = BoostConfig {
        sequence: a.sequence.clone(),
        first: a.first,
        frames: a.frames,
        real_every: a.real_every,
        real_gaps: a.real_gaps.clone(),
        bench: a.bench.clone(),
        only: a.only.clone(),
        conditions: parse_list(&a.conditions)?,
        seeds: a.seeds,
        redraw: a.redraw,
        pairs: a.pairs,
        train,
        eval: EvalConfig { samples: a.samples.clone(), seed: a.eval_seed, ..Default::default() },
        classical: load_config(&a.classical_config, &[])?,
        models: a.models.clone(),
        out: a.out.clone(),
        progress: !a.quiet,
    };
    std::fs::create_dir_all(&a.out).map_err(|e| Error::io(&a.out, e))?;
    let quiet = a.quiet;
    let report = run_boost(&cfg, &mut |m| {
        if !quiet {
            eprintln!("{m}");
        }
    })?;
    for n in &report.notes {
        writeln!(out, "{n}").map_err(w)?;
    }
    writeln!(
        out,
        "{} units scored ({} of them trained first), {} already done; tables in {}",
        report.units_run,
        report.units_trained,
        report.units_skipped,
        a.out.join("boost.txt").display()
    ).map_err(w)?;
    write!(out, "{}", report.text).map_err(w)?;
    Ok(())
}
