//! Assembles the stages of a build from its config and runs them over the units this worker owns.

use super::config::BuildConfig;
use crate::error::Result;
use crate::inpainting::InpaintConfig;
use crate::rng::unit_seed;
use crate::runtime::{run_pipeline, CancelToken, RunSummary, StageSpec};
use crate::shards::dataset::Dataset;
use crate::shards::plan::{check_worker, plan_shards, shard_count, shard_units};
use crate::shards::CODE_VERSION;
use crate::sources::Catalog;
use crate::stages::correct::Target;
use crate::stages::frame_cache::FrameCache;
use crate::stages::ingest::{Ingest, PreparedFrame};
use crate::stages::inpaint::Inpaint;
use crate::stages::pack::Pack;
use crate::stages::reproject::Reproject;
use crate::stages::scene::SceneStage;
use crate::scene::Scene;
use crate::stages::sink::ShardSink;
use crate::stages::PairUnit;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;

/// How a build runs (nothing here changes the pairs it produces).
#[derive(Clone, Debug)]
pub struct BuildOptions {
    /// The dataset folder.
    pub out: PathBuf,
    /// This worker's index and the number of workers: the worker takes shards `k` with `k mod workers == worker`.
    pub worker: u64,
    pub workers: u64,
    /// Stop at the first bad input instead of recording an `input_error` row.
    pub strict: bool,
    /// Draw progress bars (on a terminal).
    pub progress: bool,
    /// Frames kept prepared (decoded, resized, back-projected) for their next samples; 0 prepares each
    /// unit's frame anew. Memory: about 1 MB per frame at the working size 256. (`build` only: labels
    /// read their windows' frames once each anyway.)
    pub frame_cache: usize,
    /// Scenes kept fused for the next units of their block (`scene` methods only); 0 fuses each unit's
    /// scene anew. Memory: a few tens of MB per scene at the default 1 cm voxels.
    pub scene_cache: usize,
    /// Where the networks of the config (correction U-Net, diffusion model) run. A build on the CPU gives
    /// the same rows whatever the thread count; on a GPU the networks' floating-point results may differ.
    pub device: tch::Device,
}

impl BuildOptions {
    /// Frames kept by default: enough for the frames in flight on every worker thread.
    pub const FRAME_CACHE: usize = 16;
    /// Scenes kept by default: units come in frame order, so the block in work and the next one.
    pub const SCENE_CACHE: usize = 2;

    /// One worker of one, building into `out`: not strict, no progress bars, the default caches.
    pub fn into_folder(out: impl Into<PathBuf>) -> Self {
        BuildOptions {
            out: out.into(),
            worker: 0,
            workers: 1,
            strict: false,
            progress: false,
            frame_cache: Self::FRAME_CACHE,
            scene_cache: Self::SCENE_CACHE,
            device: tch::Device::Cpu,
        }
    }
}

/// The caches the stages of one build share.
struct Caches {
    frames: Arc<FrameCache<PreparedFrame>>,
    scenes: Arc<FrameCache<Scene>>,
}

/// What a build did.
#[derive(Clone, Debug)]
pub struct BuildReport {
    pub dataset: PathBuf,
    /// The dataset's config hash (the blake3 of the config's identity, [`BuildConfig::identity`]).
    pub config_hash: String,
    pub total_units: u64,
    pub total_shards: u64,
    /// Shards this worker owns that were already committed (skipped).
    pub already_committed: u64,
    /// Shards committed by this run.
    pub committed_now: Vec<u64>,
    /// Rows committed by this run, by status.
    pub rows_by_status: BTreeMap<String, u64>,
    /// Frames this run prepared (decoded, resized, back-projected): once per frame with the frame
    /// cache, once per unit without it.
    pub frames_prepared: u64,
    /// Scenes this run fused (once per block of source frames with a `scene` method, none without).
    pub scenes_fused: u64,
    pub summary: RunSummary,
}

/// Runs the build described by `config` into `opts.out`, resuming whatever is already committed there.
pub fn run_build(config: &BuildConfig, opts: &BuildOptions, cancel: &CancelToken) -> Result<BuildReport> {
    config.validate()?;
    check_worker(opts.worker, opts.workers)?;
    let catalog = Arc::new(Catalog::open(&config.source, &config.select, config.samples_per_frame)?);
    let total_units = catalog.units();
    let total_shards = shard_count(config.shard_size, total_units);
    let identity = config.identity()?;
    let dataset = Dataset::create_or_open(&opts.out, &identity.toml, &identity.dataset_hash)?
        .with_worker(format!("{}-of-{}", opts.worker, opts.workers))
        .with_row_group_rows(config.output.row_group_rows);
    dataset.clean_stale_temps()?;
    let committed = dataset.resumable("pairs")?;
    let (owned, todo, todo_units) = plan_shards(total_units, config.shard_size, opts.worker, opts.workers, &committed);

    let units = {
        let catalog = catalog.clone();
        let (seed, shard_size) = (config.seed, config.shard_size);
        todo.clone().into_iter().flat_map(move |k| {
            let (a, b) = shard_units(k, shard_size, total_units);
            a..b
        })
        .map(move |u| {
            let (fi, si) = catalog.unit(u);
            let f = &catalog.frames[fi];
            PairUnit::new(u, fi, si, unit_seed(seed, &f.key, si as u64), f.scene.clone(), f.key.clone())
        })
    };
    let frames = Arc::new(FrameCache::new(opts.frame_cache));
    let scenes = Arc::new(FrameCache::new(opts.scene_cache));
    let caches = Caches { frames: frames.clone(), scenes: scenes.clone() };
    let stages = build_stages(config, &identity.content_hash, catalog, caches, opts, rayon::current_num_threads())?;
    let mut sink = ShardSink::new(&dataset, config.shard_size, total_units, todo);
    let summary = run_pipeline(units, stages, &mut sink, todo_units, opts.progress, cancel)?;
    Ok(BuildReport {
        dataset: opts.out.clone(),
        config_hash: identity.dataset_hash,
        total_units,
        total_shards,
        already_committed: (owned.len() - sink.shards.len()) as u64,
        committed_now: sink.committed.clone(),
        rows_by_status: sink.rows_by_status.clone(),
        frames_prepared: frames.made(),
        scenes_fused: scenes.made(),
        summary,
    })
}

/// The stages of the build pipeline, in order, each replicated over `threads` workers (a unit's work
/// is a few milliseconds, so parallelism across units is what fills the cores; the sink restores unit
/// order within each shard).
fn build_stages(
    config: &BuildConfig,
    content_hash: &str,
    catalog: Arc<Catalog>,
    caches: Caches,
    opts: &BuildOptions,
    threads: usize,
) -> Result<Vec<StageSpec<PairUnit>>> {
    let Caches { frames, scenes } = caches;
    let (strict, device) = (opts.strict, opts.device);
    let w = &config.working;
    let n = threads;
    let mut inpainters = (0..n).map(|_| config.inpaint.build_on(device)).collect::<Result<Vec<_>>>()?.into_iter();
    let sv = &config.successive;
    // Successive views come one after another (each needs the memory the previous one grew), so their
    // inpainter fills one view per forward pass.
    let mut one_at_a_time = config.inpaint.clone();
    if let InpaintConfig::Diffusion(d) = &mut one_at_a_time {
        d.batch = 1;
    }
    let mut successive_inpainters = match sv.is_off() {
        true => Vec::new(),
        false => (0..n).map(|_| one_at_a_time.build()).collect::<Result<Vec<_>>>()?,
    }
    .into_iter();
    let mut stages = vec![
        StageSpec::replicated(n, || Ingest {
            catalog: catalog.clone(),
            working: w.clone(),
            strict,
            frames: frames.clone(),
            voxel: config.voxelize.voxel,
            depth_maps: config.output.depth_maps,
        }),
        StageSpec::replicated(n, || {
            config.pose.build(&config.correct.condition, w.depth_range(), w.crop_box, config.voxelize.voxel, config.validate.radius)
        }),
        StageSpec::replicated(n, || Reproject),
    ];
    if config.uses_scene() {
        stages.push(StageSpec::replicated(n, || SceneStage { catalog: catalog.clone(), config: config.scene.clone(), scenes: scenes.clone() }));
    }
    let scene_fill = config.inpaint.is_scene();
    stages.extend([
        StageSpec::replicated(n, || config.correct.build(Target::Condition, device)),
        StageSpec::replicated(n, || Inpaint { inpainter: inpainters.next().expect("one inpainter per worker"), scene: scene_fill }),
        StageSpec::replicated(n, || config.correct.build(Target::Output, device)),
    ]);
    if !sv.is_off() {
        stages.push(StageSpec::replicated(n, || {
            let inpainter = successive_inpainters.next().expect("one inpainter per worker");
            sv.build(&config.pose, &config.correct, inpainter, w)
        }));
    }
    stages.extend([
        StageSpec::replicated(n, || config.voxelize.build(w)),
        StageSpec::replicated(n, || config.validate.build()),
        StageSpec::replicated(n, || Pack {
            config_hash: content_hash.to_string(),
            code_version: CODE_VERSION.to_string(),
            stages_json: stages_json(config),
            depth_maps: config.output.depth_maps,
            size: w.size,
        }),
    ]);
    Ok(stages)
}

/// The provenance record of the stages: names and parameters (and model hashes when models exist), with
/// paths as the config file wrote them (the same rows wherever the build ran).
fn stages_json(resolved: &BuildConfig) -> String {
    let config = &crate::config_paths::relative_to_folder(resolved);
    let (c, i, o) = (&resolved.correct.condition, &resolved.inpaint, &resolved.correct.output);
    let (condition_model, inpaint_model, output_model) = (model_hash(c.checkpoint()), model_hash(i.checkpoint()), model_hash(o.checkpoint()));
    let successive = (!config.successive.is_off()).then(|| serde_json::json!({"stage": "successive", "params": config.successive}));
    let scene = config.uses_scene().then(|| serde_json::json!({"stage": "scene", "params": config.scene}));
    let v: Vec<serde_json::Value> = [
        serde_json::json!({"stage": "ingest", "select": config.select, "working": config.working}),
        serde_json::json!({"stage": "pose", "sampler": "pivot", "params": config.pose}),
        serde_json::json!({"stage": "reproject", "zbuffer": "nearest", "rounding": "half_even"}),
    ]
    .into_iter()
    .chain(scene)
    .chain([
        serde_json::json!({"stage": "correct_condition", "params": config.correct.condition, "model_blake3": condition_model}),
        serde_json::json!({"stage": "inpaint", "params": config.inpaint, "model_blake3": inpaint_model}),
        serde_json::json!({"stage": "correct_output", "params": config.correct.output, "model_blake3": output_model}),
    ])
    .chain(successive)
    .chain([
        serde_json::json!({"stage": "voxelize", "params": config.voxelize}),
        serde_json::json!({"stage": "validate", "params": config.validate}),
    ])
    .collect();
    serde_json::Value::Array(v).to_string()
}

/// blake3 of a stage's model (None without a model; the file was read by validation before).
fn model_hash(path: Option<crate::nn::ModelPath>) -> Option<String> {
    path.and_then(|p| p.blake3().ok())
}
