//! The training pairs of the boost conditions: real single-frame pairs of the training frames with their
//! captured poses (made as `fragments --single-frames` makes them), and generated pairs built in-process
//! from the same frames by the build pipeline (the library path `pointreggpt build` runs).

use super::conditions::Generator;
use crate::error::{Error, Result};
use crate::pipeline::overrides::apply_override;
use crate::pipeline::{run_build, BuildConfig, BuildOptions};
use crate::registration::benchmark::make::{pair_truths, single_frame_cloud};
use crate::runtime::CancelToken;
use crate::shards::dataset::Dataset;
use crate::shards::Status;
use crate::sources::{open_sequences, Layout, Sequence};
use crate::stages::ingest::WorkingConfig;
use crate::stages::voxelize::VoxelizeConfig;
use crate::geometry::pose_from_rows;
use crate::training::descriptor::data::TrainPair;
use std::path::Path;

/// A training pair with its overlap (the larger of the two directions' fractions, as the validate stage
/// and the benchmark define it).
#[derive(Clone)]
pub struct OverlapPair {
    pub pair: TrainPair,
    pub overlap: f64,
}

/// The one posed sequence at `path` (any layout `fragments` reads).
pub fn open_one(path: &Path) -> Result<Sequence> {
    let mut seqs = open_sequences(path, Layout::Auto)?;
    match seqs.len() {
        1 => Ok(seqs.remove(0)),
        n => Err(Error::input(path, format!("holds {n} sequences; eval boost trains on one (give its folder)"))),
    }
}

/// Real pairs (f, f + g) of frames `first .. first + frames` (both frames in the range) for f every
/// `every` frames and g in `gaps`, with overlap of at least 10 %: source = frame f + g, target = frame f,
/// the pose from the captured camera poses. `tick` after each frame's cloud.
pub fn real_pairs(seq: &Sequence, first: usize, frames: usize, every: usize, gaps: &[usize], tick: &mut dyn FnMut()) -> Result<Vec<OverlapPair>> {
    let end = (first + frames).min(seq.frames.len());
    let (working, voxelize) = (WorkingConfig::default(), VoxelizeConfig::default());
    let mut clouds = Vec::new();
    for f in first..end {
        clouds.push(single_frame_cloud(seq, f, &working, &voxelize)?);
        tick();
    }
    let keep = |i: usize, j: usize| (i - first) % every.max(1) == 0 && gaps.contains(&(j - i));
    let truths = pair_truths(&clouds, seq.frames.len(), 1.0, &keep);
    let cloud = |index: usize| &clouds[index - first].points;
    let mut out: Vec<OverlapPair> = truths
        .into_iter()
        .map(|t| OverlapPair {
            pair: TrainPair {
                key: format!("{}/{}/{}", seq.name, t.gt.i, t.gt.j),
                source: cloud(t.gt.j).clone(),
                target: cloud(t.gt.i).clone(),
                t_target_from_source: t.gt.t_i_from_j,
            },
            overlap: t.overlap,
        })
        .collect();
    out.sort_by(|a, b| a.pair.key.cmp(&b.pair.key));
    Ok(out)
}

/// The build config of `generator`: the classical pipeline config with the generator's overrides, its
/// source the sequence at `sequence` (frames `first .. first + frames`), `samples_per_frame` target views
/// per frame.
pub fn generator_config(classical: &BuildConfig, generator: Generator, models: &Path, sequence: &Path, first: usize, frames: usize, samples_per_frame: u32) -> Result<BuildConfig> {
    let mut doc: toml::Table = classical.to_toml().parse().map_err(|e: toml::de::Error| Error::Internal(format!("classical config: {e}")))?;
    let path = toml::Value::String(sequence.display().to_string());
    let mut sets = vec![
        ("source".to_string(), format!(r#"{{ kind = "directory", path = {path}, layout = "auto" }}"#)),
        ("select".to_string(), format!("{{ every = 1, offset = {first}, max_per_sequence = {frames} }}")),
        ("samples_per_frame".to_string(), samples_per_frame.to_string()),
    ];
    sets.extend(generator.overrides(models));
    for (k, v) in sets {
        apply_override(&mut doc, &format!("{k}={v}"))?;
    }
    let config: BuildConfig = toml::Value::Table(doc)
        .try_into()
        .map_err(|e: toml::de::Error| Error::config(format!("eval boost: the {} generator's config", generator.name()), e.to_string()))?;
    config.validate()?;
    Ok(config)
}

/// Builds (or resumes) the dataset of `config` in `out` and returns its `ok` pairs in unit order.
pub fn generated_pairs(config: &BuildConfig, out: &Path, progress: bool) -> Result<Vec<OverlapPair>> {
    let opts = BuildOptions { out: out.to_path_buf(), worker: 0, workers: 1, strict: false, progress };
    run_build(config, &opts, &CancelToken::new())?;
    let mut rows = Dataset::open(out)?.read_pairs()?;
    rows.sort_by_key(|r| r.unit_index);
    rows.into_iter()
        .filter(|r| r.status == Status::Ok && !r.source_points.is_empty() && !r.target_points.is_empty())
        .map(|r| {
            let t = pose_from_rows(&r.t_target_from_source).map_err(|e| Error::input(out, format!("pair {}: {e}", r.pair_key)))?;
            Ok(OverlapPair {
                overlap: r.overlap_source.max(r.overlap_target),
                pair: TrainPair { key: r.pair_key, source: r.source_points, target: r.target_points, t_target_from_source: t },
            })
        })
        .collect()
}
