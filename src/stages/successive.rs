//! Successive views (reference §3.3, `num_samples > 1`): after the first target view, draw more views, each
//! re-projected from a scene memory that grows with the views generated so far, and fuse them all into the
//! pair's target cloud; and the `[successive]` config section.

use super::correct::{correct_condition, correct_output, CorrectConfig};
use super::ingest::WorkingConfig;
use super::pose::PoseConfig;
use super::inpaint::noise_seed;
use super::{streams, PairUnit};
use crate::correction::Corrector;
use crate::error::{Error, Result};
use super::voxelize::tagged_view_points;
use crate::geometry::projection::NO_SOURCE;
use crate::geometry::{
    project_zbuffer, transform_points, voxel_downsample_tagged, AxisBox, DepthMap, DepthRange, Intrinsics, PivotPoseSampler,
    Point, PointTag, Projection,
};
use crate::inpainting::{InpaintContext, Inpainter};
use crate::rng::Rng;
use crate::runtime::Stage;
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

/// The official `num_samples > 1` generation (reference §2, §3.3): the pair's target is several views at
/// independently drawn poses (each relative to the source camera); every view is re-projected from a scene
/// memory that holds the source points and the views generated so far (voxel-downsampled), corrected and
/// inpainted like the first, and the views are fused into one target cloud in the first view's camera.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SuccessiveConfig {
    /// Target views fused into the target cloud (1 = off, one view per pair).
    pub views: u32,
    /// Voxel of the scene memory after each view is added, metres (official `memory_voxel_size` 0.002).
    pub memory_voxel: f32,
}

impl Default for SuccessiveConfig {
    fn default() -> Self {
        SuccessiveConfig { views: 1, memory_voxel: 0.002 }
    }
}

impl SuccessiveConfig {
    pub fn is_off(&self) -> bool {
        self.views <= 1
    }

    /// Checks ranges; errors name the key under `successive`.
    pub fn validate(&self) -> Result<()> {
        if self.views == 0 || self.views > 64 {
            return Err(Error::config("successive.views", "must be 1..=64"));
        }
        if !(self.memory_voxel.is_finite() && self.memory_voxel >= 0.0005 && self.memory_voxel <= 0.1) {
            return Err(Error::config("successive.memory_voxel", "must be 0.0005..=0.1 metres"));
        }
        Ok(())
    }

    /// The stage: views drawn by the `pose` sampler, corrected as `correct` says, filled by `inpainter`.
    pub fn build(&self, pose: &PoseConfig, correct: &CorrectConfig, inpainter: Box<dyn Inpainter>, working: &WorkingConfig) -> Successive {
        Successive {
            views: self.views,
            memory_voxel: self.memory_voxel,
            sampler: pose.pivot_sampler(),
            condition: correct.condition.build(),
            inpainter,
            output: correct.output.build(),
            depth_range: working.depth_range(),
            crop_box: working.crop_box,
        }
    }
}

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
        // The fragment (all views, source frame) and the scene memory (source points + views so far), each
        // point tagged with its provenance: in the memory, `known` is the share of a point's voxel traced
        // back to the source frame. The unit's own memory stays the source cloud.
        let (mut fragment, mut fragment_tags) = self.view_points(first, &k, &t_first, &unit.known, 0);
        let source_tags = vec![PointTag { known: 1.0, scene: 0.0, view: 0 }; unit.memory.len()];
        let (mut memory, mut memory_tags) = voxel_downsample_tagged(
            &[unit.memory.as_slice(), &fragment].concat(),
            &[source_tags.as_slice(), &fragment_tags].concat(),
            self.memory_voxel,
        );
        for view in 1..self.views {
            let t = self.sampler.sample(&mut Rng::new(unit.seed).fork(streams::POSE).fork(view as u64));
            let (depth, known) = self.generate(&memory, &memory_tags, &t, &k, noise_seed(unit.seed, view));
            let (points, tags) = self.view_points(&depth, &k, &t, &known, view as u8);
            if view + 1 < self.views {
                // The last view feeds no other: its points only join the fragment.
                (memory, memory_tags) = voxel_downsample_tagged(
                    &[memory.as_slice(), &points].concat(),
                    &[memory_tags.as_slice(), &tags].concat(),
                    self.memory_voxel,
                );
            }
            fragment.extend(points);
            fragment_tags.extend(tags);
        }
        // The fused target, in the first view's camera, cropped like a single view's cloud.
        unit.fused_target = Some(self.crop_box.crop_with(&transform_points(&fragment, &t_first), &fragment_tags));
        Ok(())
    }
}
impl Successive {
    /// One view: re-project the memory into camera `t`, correct the condition, inpaint, correct the output.
    /// Returns the depth and which of its pixels trace back to the source frame (known after the
    /// correction, and won by a memory point whose voxel is mostly source-traced).
    fn generate(&self, memory: &[Point], memory_tags: &[PointTag], t: &Isometry3<f64>, k: &Intrinsics, seed: u64) -> (DepthMap, Vec<bool>) {
        let Projection { depth: mut condition, mut known, source_index } = project_zbuffer(memory, t, k, true);
        correct_condition(self.condition.as_ref(), None, &mut condition, &mut known);
        let mut depth = self.inpainter.inpaint(&condition, &known, &InpaintContext { intrinsics: *k, seed, t_target_from_source: *t });
        correct_output(self.output.as_ref(), None, &mut depth);
        let winners = source_index.expect("asked for the source index");
        let traced = known.iter().zip(&winners).map(|(&kn, &i)| kn && i != NO_SOURCE && memory_tags[i as usize].known >= 0.5).collect();
        (depth, traced)
    }

    /// A view's points (depth range applied) moved into the source camera frame, tagged with `view` and
    /// whether their pixel is `known`.
    fn view_points(&self, depth: &DepthMap, k: &Intrinsics, t_view_from_source: &Isometry3<f64>, known: &[bool], view: u8) -> (Vec<Point>, Vec<PointTag>) {
        let (points, tags) = tagged_view_points(depth, k, self.depth_range, known, &[], view);
        (transform_points(&points, &t_view_from_source.inverse()), tags)
    }
}
