//! [`BoostConfig`]: everything an `eval boost` run needs (the training frames and pools, the conditions,
//! the training and evaluation settings), shared by the draws ([`super::draw`]) and the run ([`super::run`]).

use super::conditions::{Condition, Generator};
use super::data::SourceFrames;
use crate::pipeline::BuildConfig;
use crate::registration::EvalConfig;
use crate::sources::OpenOptions;
use crate::training::descriptor::train::DescriptorTrainOptions;
use std::path::PathBuf;

/// One training sequence: its folder and frames `first .. first + frames`.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainingSequence {
    pub path: PathBuf,
    pub first: usize,
    pub frames: usize,
}

/// Everything a boost run needs.
pub struct BoostConfig {
    /// The training sequences (one or more; real pairs and generated pairs come from each).
    pub sequences: Vec<TrainingSequence>,
    /// How the sequences are opened (layout, and intrinsics / depth scale replacing the layout's own).
    pub open: OpenOptions,
    /// Frames without a camera pose are an error (default: left out of the real pairs and counted).
    pub strict: bool,
    /// Real single-frame pairs: a source frame every `real_every` frames, partners `real_gaps` frames later.
    pub real_every: usize,
    pub real_gaps: Vec<usize>,
    /// Real fragment pairs: fragments of `fragment_frames` frames every `fragment_stride` frames.
    pub fragment_frames: usize,
    pub fragment_stride: usize,
    /// Where generated pairs take their source frames from.
    pub source_frames: SourceFrames,
    /// The generator whose pairs' source-side overlap histogram the real single-frame pairs are matched to.
    pub reference: Generator,
    /// The evaluation benchmark folders, and the benchmarks of them to score (empty: all).
    pub bench: Vec<PathBuf>,
    pub only: Vec<String>,
    /// Tables per (benchmark, scene) instead of per benchmark.
    pub by_scene: bool,
    pub conditions: Vec<Condition>,
    /// Paired differences asked for besides the default ones (names).
    pub compare: Vec<(String, String)>,
    pub seeds: u64,
    /// Each training seed k > 0 also draws its own training pairs (real and generated, from the same
    /// pools); seed 0 keeps the protocol's draw. The spread over seeds then covers the draw too.
    pub redraw: bool,
    /// Training pairs per condition without a real base, the most real base pairs, and the generated
    /// pool's size beyond what the mixes need.
    pub pairs: usize,
    /// The descriptor training settings (`out`, `seed`, `resume` are set per unit).
    pub train: DescriptorTrainOptions,
    pub eval: EvalConfig,
    /// The classical generator's pipeline config (the other generators override its correction and fill).
    pub classical: BuildConfig,
    /// Folder of the neural generator's checkpoints.
    pub models: PathBuf,
    pub out: PathBuf,
    pub progress: bool,
}
