//! The label pipeline's operators: fuse a window, then sample, re-project and label; and its sink.

use super::config::{DenseMode, LabelsConfig};
use super::label::keep_label;
use super::windows::Window;
use crate::error::{Error, Result};
use crate::geometry::{pose_to_rows, project_zbuffer, relative_pose, voxel_downsample, Intrinsics, Point, ResizeCrop};
use crate::pipeline::catalog::Catalog;
use crate::pipeline::config::IntrinsicsMap;
use crate::rng::Rng;
use crate::runtime::{Item, Sink, Stage};
use crate::shards::dataset::Dataset;
use crate::shards::labels::{labels_to_batch, LabelRow, LABELS_TABLE};
use crate::shards::row::Status;
use crate::sources::depth_png::encode_depth_png;
use crate::stages::pack::encode_mask_png;
use crate::tsdf::TsdfVolume;
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
    /// Working intrinsics of the reference camera.
    pub k: Option<Intrinsics>,
    /// Dense surface points and their sparse copy, reference camera frame, cropped to the box.
    pub dense: Vec<Point>,
    pub sparse: Vec<Point>,
    /// The fused volume, kept until the label stage when `I_d` is ray cast.
    pub volume: Option<TsdfVolume>,
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
        let t_world_from_ref = reference
            .t_world_from_camera
            .ok_or_else(|| Error::input(&reference.depth_path, "frame has no camera pose (missing pose file)"))?;
        let mut volume = TsdfVolume::new(self.config.tsdf.clone())?;
        for &i in &u.window.frames {
            let f = self.catalog.load(i)?;
            let pose = f.t_world_from_camera.ok_or_else(|| Error::input(&f.depth_path, "frame has no camera pose (missing pose file)"))?;
            volume.integrate(&f.depth, &f.intrinsics, &relative_pose(&t_world_from_ref, &pose))?;
        }
        let w = &self.config.working;
        let dense = w.crop_box.crop(&volume.extract_points(self.config.clouds.weight_threshold));
        if dense.is_empty() {
            return Err(Error::input(&reference.depth_path, "the fused window has no surface inside the crop box"));
        }
        let k0 = &reference.intrinsics;
        let rc = ResizeCrop::official(k0.width, k0.height, w.size)?;
        u.k = Some(match w.intrinsics {
            IntrinsicsMap::Official => rc.official_intrinsics(k0)?,
            IntrinsicsMap::Exact => rc.exact_intrinsics(k0)?,
        });
        u.sparse = voxel_downsample(&dense, self.config.clouds.sparse_voxel);
        u.dense = dense;
        if self.config.clouds.dense == DenseMode::Raycast {
            u.volume = Some(volume);
        }
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
            intrinsics: u.k.map(|k| k.as_vector()).unwrap_or([0.0; 4]),
            t_target_from_reference: pose_to_rows(&nalgebra::Isometry3::identity()),
            tsdf_voxel: c.tsdf.voxel_size_m,
            sparse_voxel: c.clouds.sparse_voxel,
            tau_gt: c.tau_gt,
            dense_points: u.dense.len() as u64,
            sparse_points: u.sparse.len() as u64,
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
        let k = u.k.expect("fuse sets the intrinsics");
        let sampler = c.pose.pivot_sampler();
        for sample in 0..c.samples_per_window {
            let mut row = base(sample);
            let mut rng = Rng::new(row.seed).fork(crate::stages::streams::POSE);
            let t = sampler.sample(&mut rng);
            let points = project_zbuffer(&u.dense, &t, &k, false).depth;
            let dense = match &u.volume {
                Some(v) => fill_holes(v.raycast(&k, &t.inverse())?, &points),
                None => points,
            };
            let sparse = project_zbuffer(&u.sparse, &t, &k, false).depth;
            let keep = keep_label(&sparse, &dense, c.tau_gt);
            row.sparse_pixels = sparse.data().iter().filter(|z| **z > 0.0).count() as u64;
            row.dropped_pixels = sparse.data().iter().zip(&keep).filter(|(z, k)| **z > 0.0 && !**k).count() as u64;
            row.t_target_from_reference = pose_to_rows(&t);
            row.sparse_depth_png = encode_depth_png(k.width, k.height, &sparse.to_raw(1000.0))?;
            row.dense_depth_png = encode_depth_png(k.width, k.height, &dense.to_raw(1000.0))?;
            row.label_png = encode_mask_png(&keep, k.width, k.height)?;
            u.rows.push(row);
        }
        u.dense = Vec::new();
        u.sparse = Vec::new();
        u.volume = None;
        Ok(())
    }
}

/// `raycast` with its empty pixels taken from the z-buffered dense points (the ray misses thin edges
/// of the observed region that the extracted points still cover).
fn fill_holes(mut raycast: crate::geometry::DepthMap, points: &crate::geometry::DepthMap) -> crate::geometry::DepthMap {
    for (r, p) in raycast.data_mut().iter_mut().zip(points.data()) {
        if *r == 0.0 {
            *r = *p;
        }
    }
    raycast
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
        let (first, end) = crate::pipeline::catalog::shard_units(shard, self.shard_size, self.total_units);
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
