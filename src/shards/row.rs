//! One row of a pairs shard: a work unit's result (accepted or rejected) with its provenance.

use crate::geometry::Point;
use serde::{Deserialize, Serialize};

/// What became of a work unit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// A valid pair.
    Ok,
    /// Rejected: the overlap keep rule failed.
    LowOverlap,
    /// Rejected: a cloud has fewer points than required after voxelization.
    TooFewPoints,
    /// The source frame could not be read or is unusable (message says why, naming the file).
    InputError,
}

impl Status {
    /// The name stored in the `status` column.
    pub fn as_str(&self) -> &'static str {
        match self {
            Status::Ok => "ok",
            Status::LowOverlap => "low_overlap",
            Status::TooFewPoints => "too_few_points",
            Status::InputError => "input_error",
        }
    }

    /// Parses a `status` column value.
    pub fn parse(s: &str) -> Option<Status> {
        [Status::Ok, Status::LowOverlap, Status::TooFewPoints, Status::InputError].into_iter().find(|v| v.as_str() == s)
    }
}

/// Wall time one stage spent on a unit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageTiming {
    pub stage: String,
    pub ms: f64,
}

/// One row of the `pairs` table (schema v3, `schemas/pairs-v3.md`).
///
/// Clouds are each in their own camera frame; `t_target_from_source` maps source-camera points into the
/// target camera (`p_t = R·p_s + t`), row-major 4×4.
#[derive(Clone, Debug, PartialEq)]
pub struct PairRow {
    /// Global index of the work unit (frame index × samples per frame + sample index).
    pub unit_index: u64,
    /// `<frame_key>#<sample_index>`, unique in a dataset.
    pub pair_key: String,
    /// Sequence (scene) name.
    pub scene: String,
    pub frame_key: String,
    pub sample_index: u32,
    /// Path of the source depth file (or `synthetic://...`).
    pub source_path: String,
    /// blake3 of the source depth file's bytes, hex.
    pub source_hash: String,
    pub status: Status,
    /// Why the unit was rejected (empty for `ok`).
    pub message: String,
    /// The unit's seed (every random draw of the unit comes from it).
    pub seed: u64,
    /// Working image size (both cameras), pixels.
    pub width: u32,
    pub height: u32,
    /// `[fx, fy, cx, cy]` of the source and target cameras at the working resolution.
    pub source_intrinsics: [f64; 4],
    pub target_intrinsics: [f64; 4],
    /// Row-major 4×4 `T_target_from_source` (identity for input errors).
    pub t_target_from_source: [f64; 16],
    /// How many poses the sampler drew before accepting one.
    pub pose_draws: u32,
    /// Frames fused into the unit's scene (the posed frames around the source frame that a `scene`
    /// method ray-casts); 0 when the unit took the single-map path (no `scene` method, or no pose).
    pub scene_frames: u32,
    /// Voxelized clouds, each in its own camera frame, metres.
    pub source_points: Vec<Point>,
    pub target_points: Vec<Point>,
    /// Per target point: the share of its voxel's points re-projected from the source frame (1 = all
    /// re-projected, 0 = all made by the fill). Empty when unknown (version-1 datasets, input errors).
    pub target_known_share: Vec<f32>,
    /// Per target point: the share of its voxel's points that the scene gave (seen by the posed frames
    /// around the source). `1 − known − scene` is the share a fill made up. Empty when unknown.
    pub target_scene_share: Vec<f32>,
    /// Per target point: the first target view (0 = the pair's first) whose points fall in its voxel; all
    /// 0 without successive views. Empty when unknown.
    pub target_view: Vec<u8>,
    /// Fraction of source points with a target neighbour within the radius, and the reverse.
    pub overlap_source: f64,
    pub overlap_target: f64,
    /// 16-bit millimetre PNGs at the working resolution (empty when not stored): the source depth, the
    /// re-projected condition after correction, and the final (inpainted, corrected) target depth.
    pub source_depth_png: Vec<u8>,
    pub condition_depth_png: Vec<u8>,
    pub target_depth_png: Vec<u8>,
    /// 8-bit PNG of the known-pixel mask of the condition (255 = known); empty when not stored.
    pub known_mask_png: Vec<u8>,
    /// blake3 of the resolved pipeline config, hex.
    pub config_hash: String,
    /// `pointreggpt <version>`.
    pub code_version: String,
    /// JSON array of the stages with their parameters and model hashes.
    pub stages: String,
    /// Per-stage wall time for this unit (not part of the deterministic content).
    pub timings: Vec<StageTiming>,
}

impl Default for PairRow {
    /// An `ok` row of unit 0 with empty text, clouds and PNGs, zero intrinsics and the identity pose: a
    /// starting point for code that fills in what it needs (tests, hand-made rows).
    fn default() -> Self {
        let mut identity = [0.0; 16];
        [0, 5, 10, 15].iter().for_each(|&i| identity[i] = 1.0);
        PairRow {
            unit_index: 0,
            pair_key: String::new(),
            scene: String::new(),
            frame_key: String::new(),
            sample_index: 0,
            source_path: String::new(),
            source_hash: String::new(),
            status: Status::Ok,
            message: String::new(),
            seed: 0,
            width: 0,
            height: 0,
            source_intrinsics: [0.0; 4],
            target_intrinsics: [0.0; 4],
            t_target_from_source: identity,
            pose_draws: 0,
            scene_frames: 0,
            source_points: Vec::new(),
            target_points: Vec::new(),
            target_known_share: Vec::new(),
            target_scene_share: Vec::new(),
            target_view: Vec::new(),
            overlap_source: 0.0,
            overlap_target: 0.0,
            source_depth_png: Vec::new(),
            condition_depth_png: Vec::new(),
            target_depth_png: Vec::new(),
            known_mask_png: Vec::new(),
            config_hash: String::new(),
            code_version: String::new(),
            stages: String::new(),
            timings: Vec::new(),
        }
    }
}

impl PairRow {
    /// blake3 over every deterministic column (everything but `timings`): equal digests mean equal
    /// pairs, whatever the thread count, shard size or interruption.
    pub fn content_digest(&self) -> blake3::Hash {
        let mut h = blake3::Hasher::new();
        let mut s = |b: &[u8]| {
            h.update(&(b.len() as u64).to_le_bytes());
            h.update(b);
        };
        s(&self.unit_index.to_le_bytes());
        s(self.pair_key.as_bytes());
        s(self.scene.as_bytes());
        s(self.frame_key.as_bytes());
        s(&self.sample_index.to_le_bytes());
        s(self.source_path.as_bytes());
        s(self.source_hash.as_bytes());
        s(self.status.as_str().as_bytes());
        s(self.message.as_bytes());
        s(&self.seed.to_le_bytes());
        s(&self.width.to_le_bytes());
        s(&self.height.to_le_bytes());
        for v in self.source_intrinsics.iter().chain(&self.target_intrinsics).chain(&self.t_target_from_source) {
            s(&v.to_le_bytes());
        }
        s(&self.pose_draws.to_le_bytes());
        s(&self.scene_frames.to_le_bytes());
        for cloud in [&self.source_points, &self.target_points] {
            let bytes: Vec<u8> = cloud.iter().flat_map(|p| [p.x, p.y, p.z]).flat_map(f32::to_le_bytes).collect();
            s(&bytes);
        }
        s(&self.target_known_share.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>());
        s(&self.target_scene_share.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>());
        s(&self.target_view);
        s(&self.overlap_source.to_le_bytes());
        s(&self.overlap_target.to_le_bytes());
        s(&self.source_depth_png);
        s(&self.condition_depth_png);
        s(&self.target_depth_png);
        s(&self.known_mask_png);
        s(self.config_hash.as_bytes());
        s(self.code_version.as_bytes());
        s(self.stages.as_bytes());
        h.finalize()
    }
}
