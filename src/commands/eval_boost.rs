//! `pointreggpt eval boost`: the boost protocol of issue 16 in one resumable command (the work is in
//! [`crate::training::boost`]).

use super::build::load_config;
use crate::error::{Error, Result};
use crate::registration::EvalConfig;
use crate::training::boost::conditions::{parse_comparisons, parse_list, Condition, Source};
use crate::training::boost::data::SourceFrames;
use crate::training::boost::config::TrainingSequence;
use crate::training::boost::{run_boost, BoostConfig};
use super::train_descriptor::{DescriptorModelArgs, DescriptorTrainingArgs};
use crate::training::descriptor::train::DescriptorTrainOptions;
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
#[command(
    after_help = "A condition is raw FPFH (fpfh) or components joined by '+', each with an optional factor ':f'. Real pairs: \
'single' (real single-frame pairs (f, f+g) of the training frames with their captured poses, g in --real-gaps, overlap >= 10 %, \
subsampled so that their source-side overlap histogram (10 % bins) matches the --reference generator's pairs), 'frag' (pairs of \
fused fragments of the training frames: --fragment-frames frames every --fragment-stride frames, TSDF with the 3DMatch settings, \
every pair at >= 10 % overlap, up to --pairs), 'fragN' (N of them: the scarce-real case). Generated pairs, built in-process from \
the training frames with the build pipeline into <out>/data/<generator>/: 'reproj' (re-projection only), 'classical' \
(--classical-config: min-pool + its fill), 'nofill' (min-pool, holes left empty), 'neural' (U-Net correction + the hole-aware \
diffusion refiner, checkpoints in --models); '-lo' after one (e.g. nofill-lo) draws poses for a 3DLoMatch + 3DMatch mix \
([pose.target], bins 10-30 % and above, half each). With a real component first (the base, n pairs), the others take floor(f*n) \
pairs: 'frag+nofill:8' is the paper's 8:1 mix, 'frag+single:8' its control with real single frames instead. Without one, each \
generated component takes floor(f*--pairs). Generated pairs of all generators are drawn paired unit by unit (the same source \
frames and samples), and a condition takes the first pairs of each draw, so mixes at several ratios share their pairs. \
--source-frames fragment-starts builds them from the first frame of each fragment, as the official generator does; every-frame \
from every training frame.\n\n\
The single-frame protocol's names still work: C0 = fpfh, C1 = single, C2 = reproj, C3 = classical, C4 = neural, C5 = \
single:0.5+classical:0.5, C5x2 = single+classical, C6 = single:0.5+neural:0.5, C6x2 = single+neural (default: all nine).\n\n\
Each condition x seed trains the descriptor (--model, --steps or --epochs, the training options) into <out>/<condition>/seed-<k>/ \
and is scored on every pair of the benchmark folders with the same sampling and RANSAC seeds (--eval-seed). A unit is skipped \
when its scores on these benchmark folders and evaluation settings exist (scores-<key>.tsv): rerun the same command to resume; \
a run on other benchmarks (or --only, --samples, --eval-seed) with the same --out scores the trained units again without \
retraining them; other training settings with the same --out are refused (<out>/boost-settings.json records them). Writes \
<out>/boost.txt (the table: FMR / IR / RR mean [min-max] over seeds per condition, benchmark and sample count, and paired IR \
differences with 95 % CIs over pairs x seeds and over the seeds' mean differences, the one to read when comparing training \
conditions; with --redraw it also covers the draw of the training set), boost.csv and boost-paired.csv. The differences: the \
single-frame protocol's (C1-C0, C3-C0, C3-C2, C4-C3, C5-C1, C5x2-C1, C6-C1, C6x2-C1), each mix against its base alone, each \
single component against fpfh, and --compare."
)]
pub struct EvalBoostArgs {
    /// Evaluation benchmark folder(s) (`pointreggpt fragments` of held-out frames: fused fragments at
    /// 3DMatch and 3DLoMatch overlaps, --single-frames pairs); several are scored in one run.
    #[arg(required = true)]
    pub bench: Vec<PathBuf>,
    /// A training sequence folder (any layout `fragments` reads), optionally with its frames as
    /// `FOLDER@FIRST-LAST` (indices, inclusive: `@0-149`); without them --first and --frames apply. Repeat
    /// to train on several sequences at once: real and generated pairs come from each.
    #[arg(long, required = true)]
    pub sequence: Vec<String>,
    /// First training frame of a --sequence given without its frames.
    #[arg(long, default_value_t = 0)]
    pub first: usize,
    /// Training frames from --first on (both frames of every real pair, every fragment, and every generated
    /// pair's source lie in them).
    #[arg(long, default_value_t = 200)]
    pub frames: usize,
    #[command(flatten)]
    pub open: super::sequence_args::SequenceArgs,
    /// Stop at a training frame without a camera pose (default: leave such frames out of the real pairs
    /// and count them; generated pairs need no pose).
    #[arg(long)]
    pub strict: bool,
    /// Conditions, comma-separated (see below; default the nine of the single-frame protocol).
    #[arg(long, value_delimiter = ',')]
    pub conditions: Vec<String>,
    /// More paired differences to report, A-B by condition name, comma-separated.
    #[arg(long, value_delimiter = ',')]
    pub compare: Vec<String>,
    /// Training seeds per condition.
    #[arg(long, default_value_t = 3)]
    pub seeds: u64,
    /// Each training seed k > 0 also draws its own training pairs (real and generated, from the same pools;
    /// units in `seed-<k>-redrawn/`), so the spread and the paired intervals cover the draw of the training
    /// set, not only the network's seed. Seed 0 keeps the protocol's draw.
    #[arg(long)]
    pub redraw: bool,
    /// Training pairs of a condition without a real base; at most this many real base pairs.
    #[arg(long, default_value_t = 2000)]
    pub pairs: usize,
    /// Descriptor training steps per unit (4 pairs x 64 points each), unless --epochs.
    #[arg(long, default_value_t = 800)]
    pub steps: u64,
    #[command(flatten)]
    pub training: DescriptorTrainingArgs,
    /// The descriptor every unit trains (the patch network by default).
    #[command(flatten)]
    pub model: DescriptorModelArgs,
    /// Points sampled from each evaluation cloud, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "5000,1000,250")]
    pub samples: Vec<usize>,
    /// Only these benchmarks of the folders (comma-separated names).
    #[arg(long, value_delimiter = ',')]
    pub only: Vec<String>,
    /// Tables per benchmark and scene ("3DMatch icl-nuim-livingroom"), not pooled over the scenes of a
    /// benchmark: for benchmark folders of different scenes (cross-scene tests). Changes only the tables.
    #[arg(long)]
    pub by_scene: bool,
    /// Real single-frame pairs: a source frame every this many frames.
    #[arg(long, default_value_t = 2)]
    pub real_every: usize,
    /// Real single-frame pairs: gaps in frames between the two frames, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "5,10,15,20,25,30,40,50,60,70,80,90,100,120,140")]
    pub real_gaps: Vec<usize>,
    /// Real fragment pairs: frames fused into one fragment.
    #[arg(long, default_value_t = 50)]
    pub fragment_frames: usize,
    /// Real fragment pairs: frames between the first frames of consecutive fragments.
    #[arg(long, default_value_t = 10)]
    pub fragment_stride: usize,
    /// Source frames of the generated pairs: every training frame, or the first frame of each fragment.
    #[arg(long, value_enum, default_value = "every-frame")]
    pub source_frames: SourceFramesArg,
    /// The generator whose source-side overlap histogram the real single-frame pairs are matched to.
    #[arg(long, default_value = "classical")]
    pub reference: String,
    /// The classical generator's pipeline config (its source and frame selection are replaced); default
    /// the shipped pipelines/paper-3dmatch-classical.toml, built into the binary.
    #[arg(long, default_value = crate::pipeline::load::BUILTIN_CLASSICAL)]
    pub classical_config: PathBuf,
    /// Folder holding correction-tiny.safetensors and diffusion-tiny-holes.safetensors (neural); default
    /// the shipped models, built into the binary.
    #[arg(long, default_value = "builtin:models")]
    pub models: PathBuf,
    /// Seed of the evaluation's point sampling and RANSAC (the same for every condition).
    #[arg(long, default_value_t = 0)]
    pub eval_seed: u64,
    /// Output folder (datasets, checkpoints, scores, tables).
    #[arg(long, value_parser = crate::commands::locations::local_output)]
    pub out: PathBuf,
    /// No progress bars.
    #[arg(long)]
    pub quiet: bool,
    /// libtorch intra-op threads.
    #[arg(long, default_value_t = 1)]
    pub torch_threads: i32,
}

/// `--source-frames`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SourceFramesArg {
    EveryFrame,
    FragmentStarts,
}

pub fn run(a: &EvalBoostArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    if a.samples.is_empty() || a.samples.contains(&0) {
        return Err(Error::config("--samples", "must be positive counts, e.g. 5000,1000,250"));
    }
    if a.real_every == 0 || a.real_gaps.is_empty() || a.real_gaps.contains(&0) {
        return Err(Error::config("--real-every/--real-gaps", "must be positive"));
    }
    if a.fragment_frames == 0 || a.fragment_stride == 0 {
        return Err(Error::config("--fragment-frames/--fragment-stride", "must be positive"));
    }
    let reference = match Condition::parse(&a.reference)?.parts.as_slice() {
        [p] => match p.source {
            Source::Generated(g) => g,
            Source::Real(_) => return Err(Error::config("--reference", "must be a generator (classical, nofill, reproj, neural, ...)")),
        },
        _ => return Err(Error::config("--reference", "must be one generator")),
    };
    crate::nn::set_torch_threads(a.torch_threads)?;
    let mut train = DescriptorTrainOptions::new(a.out.clone());
    train.steps = a.steps;
    a.training.apply(&mut train);
    train.model = a.model.model()?;
    train.checkpoint_every = if a.training.epochs.is_some() { 100 } else { (a.steps / 4).clamp(1, 100) };
    train.validate()?;
    let sequences = a.sequence.iter().map(|s| parse_sequence(s, a.first, a.frames)).collect::<Result<Vec<_>>>()?;
    let cfg = BoostConfig {
        sequences,
        open: a.open.options()?,
        strict: a.strict,
        real_every: a.real_every,
        real_gaps: a.real_gaps.clone(),
        fragment_frames: a.fragment_frames,
        fragment_stride: a.fragment_stride,
        source_frames: match a.source_frames {
            SourceFramesArg::EveryFrame => SourceFrames::EveryFrame,
            SourceFramesArg::FragmentStarts => SourceFrames::FragmentStarts { per: a.fragment_frames, stride: a.fragment_stride },
        },
        reference,
        bench: a.bench.clone(),
        only: a.only.clone(),
        by_scene: a.by_scene,
        conditions: parse_list(&a.conditions)?,
        compare: parse_comparisons(&a.compare)?,
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

/// `FOLDER` (frames `first .. first + frames`) or `FOLDER@FIRST-LAST` (inclusive indices).
fn parse_sequence(s: &str, first: usize, frames: usize) -> Result<TrainingSequence> {
    let range = s.rsplit_once('@').and_then(|(path, r)| {
        let (a, b) = r.split_once('-')?;
        Some((path, a.trim().parse::<usize>().ok()?, b.trim().parse::<usize>().ok()?))
    });
    match range {
        Some((_, a, b)) if b < a => Err(Error::config("--sequence", format!("`{s}`: the last frame {b} is before the first {a}"))),
        Some((path, a, b)) => Ok(TrainingSequence { path: PathBuf::from(path), first: a, frames: b - a + 1 }),
        None => Ok(TrainingSequence { path: PathBuf::from(s), first, frames }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sequences_take_their_own_frames_or_the_flags() {
        let t = parse_sequence("data/icl@0-299", 5, 10).unwrap();
        assert_eq!((t.path, t.first, t.frames), (PathBuf::from("data/icl"), 0, 300));
        let t = parse_sequence("data/a@b/kitchen", 5, 10).unwrap();
        assert_eq!((t.path, t.first, t.frames), (PathBuf::from("data/a@b/kitchen"), 5, 10));
        assert!(parse_sequence("x@9-3", 0, 1).unwrap_err().to_string().contains("before the first"));
    }
}
