//! Voxelize: the target cloud cropped to the box in its camera frame and voxel-downsampled (ingest made the
//! source cloud the same way, once per frame), both checked for size; and the `[voxelize]` config section.

use super::ingest::WorkingConfig;
use super::PairUnit;
use crate::error::{Error, Result};
use crate::geometry::{backproject_with_pixels, voxel_downsample_tagged, AxisBox, DepthMap, DepthRange, Intrinsics, Point, PointTag};
use crate::runtime::Stage;
use crate::shards::row::Status;
use serde::{Deserialize, Serialize};

/// Voxelization of both clouds (each in its own camera frame, after the crop box).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VoxelizeConfig {
    /// Voxel edge, metres (official 0.025).
    pub voxel: f32,
    /// A pair is rejected (`too_few_points`) when either cloud has fewer points (official 1000).
    pub min_points: usize,
}

impl Default for VoxelizeConfig {
    fn default() -> Self {
        VoxelizeConfig { voxel: 0.025, min_points: 1000 }
    }
}

impl VoxelizeConfig {
    /// Checks ranges; errors name the key under `voxelize`.
    pub fn validate(&self) -> Result<()> {
        if !(self.voxel.is_finite() && self.voxel >= 0.001 && self.voxel <= 1.0) {
            return Err(Error::config("voxelize.voxel", "must be 0.001..=1 metres"));
        }
        Ok(())
    }

    /// The stage; clouds are cut to the working depth range and crop box first.
    pub fn build(&self, working: &WorkingConfig) -> Voxelize {
        Voxelize { voxel: self.voxel, min_points: self.min_points, depth_range: working.depth_range(), crop_box: working.crop_box }
    }
}

pub struct Voxelize {
    pub voxel: f32,
    pub min_points: usize,
    pub depth_range: DepthRange,
    pub crop_box: AxisBox,
}

impl Stage<PairUnit> for Voxelize {
    fn name(&self) -> &'static str {
        "voxelize"
    }

    fn process(&mut self, unit: &mut PairUnit) -> Result<()> {
        let k = unit.k.expect("ingest sets the intrinsics");
        let target = unit.target_depth.as_ref().expect("inpaint sets the target");
        let (target_points, tags) = match unit.fused_target.take() {
            Some(fused) => fused,
            None => {
                let (points, tags) = tagged_view_points(target, &k, self.depth_range, &unit.known, &unit.scene_filled, 0);
                self.crop_box.crop_with(&points, &tags)
            }
        };
        let (t, tags) = voxel_downsample_tagged(&target_points, &tags, self.voxel);
        unit.target_points = t;
        unit.target_tags = tags;
        unit.memory = Vec::new(); // no longer needed: keep items small
        let (ns, nt) = (unit.source_points.len(), unit.target_points.len());
        if ns < self.min_points || nt < self.min_points {
            unit.reject(Status::TooFewPoints, format!("source {ns} / target {nt} points at {} m voxels, need {}", self.voxel, self.min_points));
        }
        Ok(())
    }
}

/// The points of a target view's depth map (in its camera frame, within `range`), each tagged with view
/// `view`: re-projected (`known` 1) where `known` marks its pixel, seen by the scene (`scene` 1) where
/// `scene` does (empty: nowhere), made up by a fill (both 0) elsewhere.
pub fn tagged_view_points(depth: &DepthMap, k: &Intrinsics, range: DepthRange, known: &[bool], scene: &[bool], view: u8) -> (Vec<Point>, Vec<PointTag>) {
    let (points, pixels) = backproject_with_pixels(depth, k, range);
    let flag = |mask: &[bool], p: u32| mask.get(p as usize).copied().unwrap_or(false) as u8 as f32;
    let tags = pixels.iter().map(|&p| PointTag { known: flag(known, p), scene: flag(scene, p), view }).collect();
    (points, tags)
}
