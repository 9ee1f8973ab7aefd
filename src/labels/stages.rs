//! The label pipeline's operators, thin adapters over [`super::label`]: fuse a window, then sample,
//! re-project and label; and the sink that commits label shards.

use super::config::LabelsConfig;
use super::label::{fuse_window, label_view, FusedWindow};
use super::windows::Window;
use crate::error::{Error, Result};
use crate::geometry::pose_to_rows;
use crate::rng::Rng;
use crate::runtime::{Item, Sink, Stage};
use crate::shards::dataset::Dataset;
use crate::shards::labels::{labels_to_batch, LabelRow, LABELS_TABLE};
use crate::shards::row::Status;
use crate::sources::depth_png::encode_depth_png;
use crate::sources::Catalog;
use crate::stages::pack::encode_mask_png;
use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::time::Duration;

/// One window on its way to its label rows.
pub struct LabelUnit {
    pub unit_index: u64,
    pub window: Window,
    pub seed: u64,
    pub status: Status,
    pub message: String,
    /// The fused window (reference camera frame), until the label stage has used it.
    pub fused: Option<FusedWindow>,
    pub rows: Vec<LabelRow>,
    pub timings: BTreeMap<String, f64>,
}

impl Item for LabelUnit {
    fn is_rejected(&self) -> bool {
        self.status != Status::Ok
    }
    fn record_timing(&mut self, stage: &'static str, elapsed: Duration) {
        self.timings.insert(stage.to_string(), elapsed.as_secs_f64() * 1e3);
    }
    fn describe(&self) -> String {
        format!("window {} ({})", self.unit_index, self.window.key)
    }
}

/// Loads a window's frames and fuses them into the reference camera's frame.
pub struct Fuse {
    pub catalog: Arc<Catalog>,
    pub config: LabelsConfig,
    pub strict: bool,
}

impl Fuse {
    fn fuse(&self, u: &mut LabelUnit) -> Result<()> {
        let reference = self.catalog.load(u.window.reference)?;
        let frames = u.window.frames.iter().map(|&i| self.catalog.load(i));
        u.fused = Some(fuse_window(&reference, frames, &self.config)?);
        Ok(())
    }
}

impl Stage<LabelUnit> for Fuse {
    fn name(&self) -> &'static str {
        "fuse"
    }
    fn process(&mut self, u: &mut LabelUnit) -> Result<()> {
        match self.fuse(u) {
            Ok(()) => Ok(()),
            Err(e @ (Error::InputData { .. } | Error::Io { .. })) if !self.strict => {
                u.status = Status::InputError;
                u.message = e.to_string();
                Ok(())
            }
            Err(e) => Err(e),
        }
    }
}

/// Draws the target poses, re-projects both clouds and labels; turns every sample into a row (rejected
/// windows become one `input_error` row).
pub struct SampleAndLabel {
    pub config: LabelsConfig,
    pub config_hash: String,
    pub code_version: String,
    pub stages_json: String,
}

impl Stage<LabelUnit> for SampleAndLabel {
    fn name(&self) -> &'static str {
        "label"
    }
    fn handles_rejected(&self) -> bool {
        true
    }
    fn process(&mut self, u: &mut LabelUnit) -> Result<()> {
        let c = &self.config;
        let fused = u.fused.take();
        let base = |sample: u32| LabelRow {
            unit_index: u.unit_index,
            sample_index: sample,
            label_key: format!("{}#{sample}", u.window.key),
            scene: u.window.scene.clone(),
            first_frame: String::new(),
            last_frame: String::new(),
            frames: u.window.frames.len() as u32,
            reference_frame: String::new(),
            status: u.status,
            message: u.message.clone(),
            seed: crate::rng::unit_seed(c.seed, &u.window.key, sample as u64),
            width: c.working.size,
            height: c.working.size,
            intrinsics: fused.as_ref().map(|f| f.k.as_vector()).unwrap_or([0.0; 4]),
            t_target_from_reference: pose_to_rows(&nalgebra::Isometry3::identity()),
            tsdf_voxel: c.tsdf.voxel_size_m,
            sparse_voxel: c.clouds.sparse_voxel,
            tau_gt: c.tau_gt,
            dense_points: fused.as_ref().map_or(0, |f| f.dense.len() as u64),
            sparse_points: fused.as_ref().map_or(0, |f| f.sparse.len() as u64),
            sparse_pixels: 0,
            dropped_pixels: 0,
            sparse_depth_png: Vec::new(),
            dense_depth_png: Vec::new(),
            label_png: Vec::new(),
            config_hash: self.config_hash.clone(),
            code_version: self.code_version.clone(),
            stages: self.stages_json.clone(),
            timings: String::new(),
        };
        if u.status != Status::Ok {
            u.rows.push(base(0));
            return Ok(());
        }
        let fused = fused.as_ref().expect("fuse sets the window of an ok unit");
        let k = fused.k;
        let sampler = c.pose.pivot_sampler();
        for sample in 0..c.samples_per_window {
            let mut row = base(sample);
            let t = sampler.sample(&mut Rng::new(row.seed).fork(crate::stages::streams::POSE));
            let view = label_view(fused, &t, c.tau_gt)?;
            let sparse = view.sparse.data();
            row.sparse_pixels = sparse.iter().filter(|z| **z > 0.0).count() as u64;
            row.dropped_pixels = sparse.iter().zip(&view.keep).filter(|(z, k)| **z > 0.0 && !**k).count() as u64;
            row.t_target_from_reference = pose_to_rows(&t);
            row.sparse_depth_png = encode_depth_png(k.width, k.height, &view.sparse.to_raw(1000.0))?;
            row.dense_depth_png = encode_depth_png(k.width, k.height, &view.dense.to_raw(1000.0))?;
            row.label_png = encode_mask_png(&view.keep, k.width, k.height)?;
            u.rows.push(row);
        }
        Ok(())
    }
}

/// Commits label shards (a fixed range of windows each) once all their windows are in.
pub struct LabelSink<'a> {
    pub dataset: &'a Dataset,
    pub catalog: Arc<Catalog>,
    pub shard_size: u64,
    pub total_units: u64,
    pub shards: BTreeSet<u64>,
    buffers: BTreeMap<u64, Vec<LabelUnit>>,
    pub committed: Vec<u64>,
    pub rows_by_status: BTreeMap<String, u64>,
}

impl<'a> LabelSink<'a> {
    pub fn new(dataset: &'a Dataset, catalog: Arc<Catalog>, shard_size: u64, total_units: u64, shards: BTreeSet<u64>) -> Self {
        LabelSink { dataset, catalog, shard_size, total_units, shards, buffers: BTreeMap::new(), committed: Vec::new(), rows_by_status: BTreeMap::new() }
    }
}

impl Sink<LabelUnit> for LabelSink<'_> {
    fn consume(&mut self, unit: LabelUnit) -> Result<()> {
        let shard = unit.unit_index / self.shard_size;
        if !self.shards.contains(&shard) {
            return Err(Error::Internal(format!("window {} is outside this run's shards", unit.unit_index)));
        }
        let buf = self.buffers.entry(shard).or_default();
        buf.push(unit);
        let (first, end) = crate::shards::plan::shard_units(shard, self.shard_size, self.total_units);
        if buf.len() as u64 == end - first {
            let mut units = self.buffers.remove(&shard).expect("buffer");
            units.sort_by_key(|u| u.unit_index);
            let mut rows = Vec::new();
            let mut by_status = BTreeMap::new();
            for u in units {
                let timings = serde_json::to_string(&u.timings).expect("timings serialise");
                let (first_key, last_key) = (
                    self.catalog.frames[*u.window.frames.first().expect("non-empty window")].key.clone(),
                    self.catalog.frames[*u.window.frames.last().expect("non-empty window")].key.clone(),
                );
                let reference = self.catalog.frames[u.window.reference].key.clone();
                for mut r in u.rows {
                    r.first_frame = first_key.clone();
                    r.last_frame = last_key.clone();
                    r.reference_frame = reference.clone();
                    r.timings = timings.clone();
                    *by_status.entry(r.status.as_str().to_string()).or_insert(0u64) += 1;
                    rows.push(r);
                }
            }
            self.dataset.commit_shard(LABELS_TABLE, shard, first, end - first, &labels_to_batch(&rows)?, by_status.clone())?;
            for (k, v) in by_status {
                *self.rows_by_status.entry(k).or_default() += v;
            }
            self.committed.push(shard);
        }
        Ok(())
    }

    fn finish(&mut self, cancelled: bool) -> Result<()> {
        if !cancelled && !self.buffers.is_empty() {
            return Err(Error::Internal(format!("label shards {:?} did not receive all their windows", self.buffers.keys().collect::<Vec<_>>())));
        }
        Ok(())
    }
}
