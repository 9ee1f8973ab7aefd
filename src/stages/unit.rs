//! The item that flows through the build pipeline: one work unit and everything computed for it.

use crate::geometry::{DepthMap, Intrinsics, Overlap, Point, PointTag};
use crate::runtime::Item;
use crate::shards::row::{PairRow, StageTiming, Status};
use nalgebra::Isometry3;
use std::time::Duration;

/// One work unit (source frame, sample index) on its way to a row.
#[derive(Debug)]
pub struct PairUnit {
    pub unit_index: u64,
    pub frame_index: usize,
    pub sample_index: u32,
    /// The unit's seed: `unit_seed(build seed, frame key, sample index)`.
    pub seed: u64,
    pub scene: String,
    pub frame_key: String,
    pub status: Status,
    /// Why the unit was rejected.
    pub message: String,
    pub source_path: String,
    pub source_hash: String,
    /// Working-resolution intrinsics (source and target cameras share them).
    pub k: Option<Intrinsics>,
    /// The 16-bit millimetre PNG of the source depth at the working resolution (empty when not stored).
    pub source_depth_png: Vec<u8>,
    /// Source points in the crop box, full resolution (the "scene memory"), source camera frame.
    pub memory: Vec<Point>,
    /// The source frame's camera-to-world pose, when its sequence has one.
    pub t_world_from_source: Option<Isometry3<f64>>,
    pub t_target_from_source: Isometry3<f64>,
    pub pose_draws: u32,
    /// Re-projected condition (after correction) and its known-pixel mask.
    pub condition: Option<DepthMap>,
    pub known: Vec<bool>,
    /// With a `scene` method: the scene (the fused frames around the source frame) seen from the target
    /// camera, 0 where it has no surface; `None` on the single-map path (no pose, no scene method).
    pub scene_depth: Option<DepthMap>,
    /// Frames fused into the unit's scene (0: the single-map path).
    pub scene_frames: u32,
    /// Target pixels the scene filled (empty when it filled none).
    pub scene_filled: Vec<bool>,
    /// Final target depth (inpainted, corrected); with successive views, the first view's.
    pub target_depth: Option<DepthMap>,
    /// With successive views: all views fused, in the first view's camera frame, cropped to the box, with
    /// each point's provenance (the voxelize stage takes it instead of back-projecting `target_depth`).
    pub fused_target: Option<(Vec<Point>, Vec<PointTag>)>,
    /// Voxelized clouds, each in its own camera frame (the source's made by ingest, the target's by voxelize).
    pub source_points: Vec<Point>,
    pub target_points: Vec<Point>,
    /// Provenance of each voxelized target point (known share, first view).
    pub target_tags: Vec<PointTag>,
    pub overlap: Overlap,
    pub timings: Vec<StageTiming>,
    /// The finished row, filled by the pack stage.
    pub row: Option<PairRow>,
}

impl PairUnit {
    /// A fresh unit; stages fill the rest.
    pub fn new(unit_index: u64, frame_index: usize, sample_index: u32, seed: u64, scene: String, frame_key: String) -> Self {
        PairUnit {
            unit_index,
            frame_index,
            sample_index,
            seed,
            scene,
            frame_key,
            status: Status::Ok,
            message: String::new(),
            source_path: String::new(),
            source_hash: String::new(),
            k: None,
            source_depth_png: Vec::new(),
            memory: Vec::new(),
            t_world_from_source: None,
            t_target_from_source: Isometry3::identity(),
            pose_draws: 0,
            condition: None,
            known: Vec::new(),
            scene_depth: None,
            scene_frames: 0,
            scene_filled: Vec::new(),
            target_depth: None,
            fused_target: None,
            source_points: Vec::new(),
            target_points: Vec::new(),
            target_tags: Vec::new(),
            overlap: Overlap { source: 0.0, target: 0.0 },
            timings: Vec::new(),
            row: None,
        }
    }

    /// Marks the unit rejected with `status` and a reason.
    pub fn reject(&mut self, status: Status, message: impl Into<String>) {
        self.status = status;
        self.message = message.into();
    }
}

impl Item for PairUnit {
    fn is_rejected(&self) -> bool {
        self.status != Status::Ok
    }
    fn record_timing(&mut self, stage: &'static str, elapsed: Duration) {
        self.timings.push(StageTiming { stage: stage.to_string(), ms: elapsed.as_secs_f64() * 1e3 });
    }
    fn describe(&self) -> String {
        format!("unit {} ({} sample {})", self.unit_index, self.frame_key, self.sample_index)
    }
}
