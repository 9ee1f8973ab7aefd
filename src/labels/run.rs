//! Runs the label pipeline over the windows this worker owns.

use super::config::LabelsConfig;
use super::stages::{Fuse, LabelSink, LabelUnit, SampleAndLabel};
use super::windows::windows;
use crate::error::Result;
use crate::shards::plan::{check_worker, plan_shards, shard_count, shard_units};
use crate::pipeline::BuildOptions;
use crate::runtime::{run_pipeline, CancelToken, RunSummary, StageSpec};
use crate::shards::dataset::Dataset;
use crate::shards::labels::LABELS_TABLE;
use crate::shards::row::Status;
use crate::shards::CODE_VERSION;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;

/// What a label run did.
#[derive(Clone, Debug)]
pub struct LabelsReport {
    pub dataset: PathBuf,
    /// The dataset's config hash (the blake3 of [`LabelsConfig::identity`]).
    pub config_hash: String,
    pub windows: u64,
    pub total_shards: u64,
    pub already_committed: u64,
    pub committed_now: Vec<u64>,
    pub rows_by_status: BTreeMap<String, u64>,
    pub summary: RunSummary,
    /// Frames (and windows) left out for want of a camera pose.
    pub unposed: super::windows::Unposed,
}

/// Runs the label pipeline into `opts.out` (resuming what is committed there).
pub fn run_labels(config: &LabelsConfig, opts: &BuildOptions, cancel: &CancelToken) -> Result<LabelsReport> {
    config.validate()?;
    check_worker(opts.worker, opts.workers)?;
    let (catalog, windows, unposed) = windows(config, opts.strict)?;
    let catalog = Arc::new(catalog);
    let total = windows.len() as u64;
    let total_shards = shard_count(config.shard_size, total);
    let identity = config.identity()?;
    let dataset = Dataset::create_or_open(&opts.out, &identity.toml, &identity.dataset_hash)?
        .with_worker(format!("{}-of-{}", opts.worker, opts.workers));
    dataset.clean_stale_temps()?;
    let committed = dataset.resumable(LABELS_TABLE)?;
    let (owned, todo, todo_units) = plan_shards(total, config.shard_size, opts.worker, opts.workers, &committed);
    let units = {
        let (windows, shard_size, seed) = (windows.clone(), config.shard_size, config.seed);
        todo.clone().into_iter().flat_map(move |k| { let (a, b) = shard_units(k, shard_size, total); a..b }).map(move |u| {
            let window = windows[u as usize].clone();
            LabelUnit {
                unit_index: u,
                seed: crate::rng::unit_seed(seed, &window.key, 0),
                window,
                status: Status::Ok,
                message: String::new(),
                fused: None,
                rows: Vec::new(),
                timings: BTreeMap::new(),
            }
        })
    };
    let n = rayon::current_num_threads();
    let stages_json = serde_json::json!([
        {"stage": "fuse", "tsdf": config.tsdf, "window": config.window, "clouds": config.clouds, "working": config.working},
        {"stage": "label", "pose": config.pose, "tau_gt": config.tau_gt, "rule": "|I_s - I_d| < tau_gt"},
    ])
    .to_string();
    let stages = vec![
        StageSpec::replicated(n, || Fuse { catalog: catalog.clone(), config: config.clone(), strict: opts.strict }),
        StageSpec::replicated(n, || SampleAndLabel {
            config: config.clone(),
            config_hash: identity.content_hash.clone(),
            code_version: CODE_VERSION.to_string(),
            stages_json: stages_json.clone(),
        }),
    ];
    let mut sink = LabelSink::new(&dataset, catalog.clone(), config.shard_size, total, todo);
    let summary = run_pipeline(units, stages, &mut sink, todo_units, opts.progress, cancel)?;
    Ok(LabelsReport {
        dataset: opts.out.clone(),
        config_hash: identity.dataset_hash.clone(),
        windows: total,
        total_shards,
        already_committed: (owned.len() - sink.shards.len()) as u64,
        committed_now: sink.committed.clone(),
        rows_by_status: sink.rows_by_status.clone(),
        summary,
        unposed,
    })
}
