//! Successive views (reference §3.3, `num_samples > 1`): after the first target view, draw more views, each
//! re-projected from a scene memory that grows with the views generated so far, and fuse them all into the
//! pair's target cloud.

use super::correct::{correct_condition, correct_output};
use super::inpaint::noise_seed;
use super::{streams, PairUnit};
use crate::correction::Corrector;
use crate::error::Result;
use crate::geometry::{
    backproject, project_zbuffer, transform_points, voxel_downsample, AxisBox, DepthMap, DepthRange, Intrinsics,
    PivotPoseSampler, Point,
};
use crate::inpainting::{InpaintContext, Inpainter};
use crate::rng::Rng;
use crate::runtime::Stage;
use nalgebra::Isometry3;

/// Views 2..=`views` of each unit; the first came through the single-view stages.
pub struct Successive {
    pub views: u32,
    pub memory_voxel: f32,
    pub sampler: PivotPoseSampler,
    pub condition: Box<dyn Corrector>,
    pub inpainter: Box<dyn Inpainter>,
    pub output: Box<dyn Corrector>,
    pub depth_range: DepthRange,
    pub crop_box: AxisBox,
}

impl Stage<PairUnit> for Successive {
    fn name(&self) -> &'static str {
        "successive"
    }

    fn process(&mut self, unit: &mut PairUnit) -> Result<()> {
        let k = unit.k.expect("ingest sets the intrinsics");
        let t_first = unit.t_target_from_source;
        let first = unit.target_depth.as_ref().expect("inpaint sets the target");
        // The fragment (all views, source frame) and the scene memory (source points + views so far). The
        // unit's own memory stays the source cloud.
        let mut fragment = self.view_points(first, &k, &t_first);
        let mut memory = voxel_downsample(&[unit.memory.as_slice(), &fragment].concat(), self.memory_voxel);
        for view in 1..self.views {
            let t = self.sampler.sample(&mut Rng::new(unit.seed).fork(streams::POSE).fork(view as u64));
            let depth = self.generate(&memory, &t, &k, noise_seed(unit.seed, view));
            let points = self.view_points(&depth, &k, &t);
            if view + 1 < self.views {
                // The last view feeds no other: its points only join the fragment.
                memory = voxel_downsample(&[memory.as_slice(), &points].concat(), self.memory_voxel);
            }
            fragment.extend(points);
        }
        // The fused target, in the first view's camera, cropped like a single view's cloud.
        unit.fused_target = Some(self.crop_box.crop(&transform_points(&fragment, &t_first)));
        Ok(())
    }
}

impl Successive {
    /// One view: re-project the memory into camera `t`, correct the condition, inpaint, correct the output.
    fn generate(&self, memory: &[Point], t: &Isometry3<f64>, k: &Intrinsics, seed: u64) -> DepthMap {
        let proj = project_zbuffer(memory, t, k, false);
        let (mut condition, mut known) = (proj.depth, proj.known);
        correct_condition(self.condition.as_ref(), &mut condition, &mut known);
        let mut depth = self.inpainter.inpaint(&condition, &known, &InpaintContext { intrinsics: *k, seed });
        correct_output(self.output.as_ref(), &mut depth);
        depth
    }

    /// A view's points (depth range applied) moved into the source camera frame.
    fn view_points(&self, depth: &DepthMap, k: &Intrinsics, t_view_from_source: &Isometry3<f64>) -> Vec<Point> {
        transform_points(&backproject(depth, k, self.depth_range), &t_view_from_source.inverse())
    }
}
