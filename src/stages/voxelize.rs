//! Voxelize: both clouds cropped to the box in their own camera frames and voxel-downsampled.

use super::PairUnit;
use crate::error::Result;
use crate::geometry::{backproject, voxel_downsample, AxisBox, DepthRange};
use crate::runtime::Stage;
use crate::shards::row::Status;

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
        let target_points = match unit.fused_target.take() {
            Some(fused) => fused,
            None => self.crop_box.crop(&backproject(target, &k, self.depth_range)),
        };
        let (s, t) = rayon::join(|| voxel_downsample(&unit.memory, self.voxel), || voxel_downsample(&target_points, self.voxel));
        unit.source_points = s;
        unit.target_points = t;
        unit.memory = Vec::new(); // no longer needed: keep items small
        let (ns, nt) = (unit.source_points.len(), unit.target_points.len());
        if ns < self.min_points || nt < self.min_points {
            unit.reject(Status::TooFewPoints, format!("source {ns} / target {nt} points at {} m voxels, need {}", self.voxel, self.min_points));
        }
        Ok(())
    }
}
