//! The training pairs of the boost conditions: real single-frame pairs of the training frames with their
//! captured poses (made as `fragments --single-frames` makes them), real pairs of fused fragments of the
//! training frames (as `fragments --stride` makes them), and generated pairs built in-process from the
//! same frames by the build pipeline (the library path `pointreggpt build` runs).

use super::conditions::Generator;
use crate::error::{Error, Result};
use crate::geometry::voxel_downsample;
use crate::pipeline::overrides::apply_override;
use crate::pipeline::{run_build, BuildConfig, BuildOptions};
use crate::registration::benchmark::make::{fragments_within, fuse_fragment, pair_truths, single_frame_cloud, Cloud, PairTruth};
use crate::runtime::CancelToken;
use crate::shards::dataset::Dataset;
use crate::shards::Status;
use crate::sources::{open_sequences, OpenOptions, Sequence, SourceConfig};
use crate::stages::ingest::WorkingConfig;
use crate::stages::voxelize::VoxelizeConfig;
use crate::training::descriptor::data::{TrainPair, BENCH_VOXEL_M};
use crate::tsdf::TsdfConfig;
use std::path::Path;

/// A training pair with its overlaps and, for a generated pair, its work unit.
#[derive(Clone)]
pub struct OverlapPair {
    pub pair: TrainPair,
    /// The larger of the two directions' fractions (as the validate stage and the benchmark define it).
    pub overlap: f64,
    /// The source side alone: the fraction of source points with a target neighbour. A generated target
    /// without a fill is nearly all re-projected source, so its target side is ≈ 1 whatever the motion;
    /// the source side is what the motion decides, and what real pairs are matched on.
    pub source_overlap: f64,
    /// The work unit of a generated pair: pairs of different generators with the same unit share their
    /// source frame and sample (and, when the generators draw poses alike, the pose).
    pub unit: Option<u64>,
}

/// The one sequence at `path` (any layout `fragments` reads).
pub fn open_one(path: &Path, options: &OpenOptions) -> Result<Sequence> {
    let mut seqs = open_sequences(path, options.clone())?;
    match seqs.len() {
        1 => Ok(seqs.remove(0)),
        n => Err(Error::input(path, format!("holds {n} sequences; give each sequence's folder as its own --sequence"))),
    }
}

/// The real pairs of `clouds` with their ground truth: source = cloud j, target = cloud i.
fn truth_pairs(seq: &Sequence, clouds: &[Cloud], truths: Vec<PairTruth>, tag: &str) -> Vec<OverlapPair> {
    let cloud = |index: usize| &clouds.iter().find(|c| c.index == index).expect("a cloud of the pair").points;
    let mut out: Vec<OverlapPair> = truths
        .into_iter()
        .map(|t| OverlapPair {
            pair: TrainPair {
                key: format!("{}{tag}/{}/{}", seq.name, t.gt.i, t.gt.j),
                source: cloud(t.gt.j).clone(),
                target: cloud(t.gt.i).clone(),
                target_observed: Vec::new(),
                real: true,
                t_target_from_source: t.gt.t_i_from_j,
            },
            overlap: t.overlap,
            source_overlap: t.source_overlap,
            unit: None,
        })
        .collect();
    out.sort_by(|a, b| a.pair.key.cmp(&b.pair.key));
    out
}

/// Real pairs (f, f + g) of frames `first .. first + frames` (both frames in the range) for f every
/// `every` frames and g in `gaps`, with overlap of at least 10 %: source = frame f + g, target = frame f,
/// the pose from the captured camera poses; frames without a pose are left out. `tick` after each frame.
pub fn real_pairs(seq: &Sequence, first: usize, frames: usize, every: usize, gaps: &[usize], tick: &mut dyn FnMut()) -> Result<Vec<OverlapPair>> {
    let end = (first + frames).min(seq.frames.len());
    let (working, voxelize) = (WorkingConfig::default(), VoxelizeConfig::default());
    let mut clouds = Vec::new();
    for f in first..end {
        if seq.frames[f].has_pose() {
            clouds.push(single_frame_cloud(seq, f, &working, &voxelize)?);
        }
        tick();
    }
    let keep = |i: usize, j: usize| (i - first) % every.max(1) == 0 && gaps.contains(&(j - i));
    let truths = pair_truths(&clouds, seq.frames.len(), 1.0, &keep);
    Ok(truth_pairs(seq, &clouds, truths, ""))
}

/// Real pairs of fused fragments of frames `first .. first + frames`: fragment k fuses frames
/// `stride·k … stride·k + per − 1` (TSDF with the 3DMatch settings, as `fragments --stride` does),
/// voxelised at 2.5 cm; every pair of fragments with overlap of at least 10 % (3DMatch and 3DLoMatch).
/// Frames without a pose are left out of their fragments. `tick` after each fragment.
pub fn fragment_pairs(seq: &Sequence, first: usize, frames: usize, per: usize, stride: usize, tick: &mut dyn FnMut()) -> Result<Vec<OverlapPair>> {
    let end = (first + frames).min(seq.frames.len());
    let ks = fragments_within(first, end, per, stride);
    if ks.is_empty() {
        return Err(Error::config("--fragment-frames", format!("frames {first}..{end} hold no fragment of {per} frames at stride {stride}")));
    }
    let tsdf = TsdfConfig::threedmatch();
    let mut clouds = Vec::new();
    for k in ks {
        if let Some(mut c) = fuse_fragment(seq, k, per, stride, &tsdf, 1.0)? {
            c.points = voxel_downsample(&c.points, BENCH_VOXEL_M);
            clouds.push(c);
        }
        tick();
    }
    let truths = pair_truths(&clouds, clouds.len(), 1.0, &|_, _| true);
    Ok(truth_pairs(seq, &clouds, truths, "-fragments"))
}

/// Where generated pairs take their source frames from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum SourceFrames {
    /// Every training frame.
    EveryFrame,
    /// The first frame of each fragment (`first + stride·k`), as the official generator takes the first
    /// frame of each 3DMatch fragment.
    FragmentStarts { per: usize, stride: usize },
}

/// The build config of `generator`: the classical pipeline config with the generator's overrides, its
/// source the sequence at `sequence` (the source frames `from` picks in `first .. first + frames`),
/// `samples_per_frame` target views per source frame.
pub fn generator_config(
    classical: &BuildConfig,
    generator: Generator,
    models: &Path,
    (sequence, open): (&Path, &OpenOptions),
    (first, frames): (usize, usize),
    from: SourceFrames,
    samples_per_frame: u32,
) -> Result<BuildConfig> {
    let mut doc: toml::Table = classical.to_toml().parse().map_err(|e: toml::de::Error| Error::Internal(format!("classical config: {e}")))?;
    let source = SourceConfig::Directory {
        path: sequence.to_path_buf(),
        layout: open.layout,
        intrinsics: open.intrinsics,
        depth_scale: open.depth_scale,
        poses: open.poses.clone(),
    };
    let source = toml::Value::try_from(&source).map_err(|e| Error::Internal(format!("source: {e}")))?;
    let select = match from {
        SourceFrames::EveryFrame => format!("{{ every = 1, offset = {first}, max_per_sequence = {frames} }}"),
        SourceFrames::FragmentStarts { per, stride } => {
            let n = fragments_within(first, first + frames, per, stride).len();
            format!("{{ every = {stride}, offset = {first}, max_per_sequence = {n} }}")
        }
    };
    doc.insert("source".to_string(), source);
    let mut sets = vec![
        ("select".to_string(), select),
        ("samples_per_frame".to_string(), samples_per_frame.to_string()),
    ];
    sets.extend(generator.overrides(models));
    for (k, v) in sets {
        apply_override(&mut doc, &format!("{k}={v}"))?;
    }
    let mut config: BuildConfig = toml::Value::Table(doc)
        .try_into()
        .map_err(|e: toml::de::Error| Error::config(format!("eval boost: the {} generator's config", generator.name()), e.to_string()))?;
    // Paths kept from the classical config were resolved against its folder: identify them by it.
    config.folder = classical.folder.clone();
    config.validate()?;
    Ok(config)
}

/// Builds (or resumes) the dataset of `config` in `out` and returns its `ok` pairs in unit order.
pub fn generated_pairs(config: &BuildConfig, out: &Path, progress: bool) -> Result<Vec<OverlapPair>> {
    let opts = BuildOptions { progress, ..BuildOptions::into_folder(out) };
    run_build(config, &opts, &CancelToken::new())?;
    let mut rows = Dataset::open(out)?.read_pairs()?;
    rows.sort_by_key(|r| r.unit_index);
    rows.into_iter()
        .filter(|r| r.status == Status::Ok && !r.source_points.is_empty() && !r.target_points.is_empty())
        .map(|r| {
            let (overlap, source_overlap, unit) = (r.overlap_source.max(r.overlap_target), r.overlap_source, r.unit_index);
            Ok(OverlapPair { overlap, source_overlap, unit: Some(unit), pair: TrainPair::from_row(r).map_err(|e| Error::input(out, e))? })
        })
        .collect()
}
