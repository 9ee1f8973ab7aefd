//! Pose sampling: the official pivot sampler, optionally redrawn towards a target overlap histogram; and
//! its `[pose]` config section.

use super::{streams, PairUnit};
use crate::error::{Error, Result};
use super::correct::correct_condition;
use crate::correction::{CorrectionConfig, Corrector};
use crate::geometry::{project_zbuffer, view_overlap, AxisBox, DepthRange, Intrinsics, PivotPoseSampler, Point};
use crate::rng::Rng;
use crate::runtime::Stage;
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

/// How the motion scale of [`sample_towards_bin`] moves after a draw that misses its bin: up (more motion,
/// less overlap) when the estimate is above the bin, down when below.
pub const SCALE_STEP: f64 = 1.25;
/// Bounds of that scale: a quarter of the official motion up to eight times it (angles capped at 90°).
pub const SCALE_RANGE: (f64, f64) = (0.25, 8.0);

/// Pose sampling: the official pivot sampler, optionally steered towards a target overlap histogram.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PoseConfig {
    /// Largest rotation about the camera x axis, degrees (official 7.5).
    pub max_pitch_deg: f64,
    /// Largest rotation about the camera y axis, degrees (official 15).
    pub max_yaw_deg: f64,
    /// Distance of the pivot ahead of the source camera, metres (official 3).
    pub pivot_distance: f64,
    /// Standard deviation of the lateral x/y jitter, metres (official 1/3).
    pub lateral_sigma: f64,
    /// When set, redraw poses until the estimated overlap falls in the bin assigned to the unit.
    pub target: Option<OverlapTarget>,
}

impl Default for PoseConfig {
    fn default() -> Self {
        let p = PivotPoseSampler::default();
        PoseConfig {
            max_pitch_deg: p.max_pitch.to_degrees(),
            max_yaw_deg: p.max_yaw.to_degrees(),
            pivot_distance: p.pivot_distance,
            lateral_sigma: p.lateral_sigma,
            target: None,
        }
    }
}

/// A target overlap histogram: each unit is assigned a bin (by its seed, with the given weights), and
/// poses are redrawn until the estimated overlap falls in that bin: the `overlap_source` the pair would
/// have if its target were the corrected re-projection alone ([`OverlapEstimate::of`]; the fill adds a
/// little). Draws start from the official sampler; after each miss the
/// motion is scaled up (overlap too high) or down (too low) by [`SCALE_STEP`], so bins the official motion
/// rarely reaches (3DLoMatch's 10–30 %) are reached too.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OverlapTarget {
    /// Bin edges of the overlap ratio, increasing, in [0, 1] (e.g. [0.1, 0.3, 1.0] for 3DLoMatch + 3DMatch).
    pub bin_edges: Vec<f64>,
    /// Relative share of pairs wanted in each bin (one fewer than the edges).
    pub weights: Vec<f64>,
    /// Most poses drawn per unit; the closest draw is kept when none lands in the bin.
    #[serde(default = "default_max_draws")]
    pub max_draws: u32,
}

fn default_max_draws() -> u32 {
    32
}

impl PoseConfig {
    pub fn pivot_sampler(&self) -> PivotPoseSampler {
        PivotPoseSampler {
            max_pitch: self.max_pitch_deg.to_radians(),
            max_yaw: self.max_yaw_deg.to_radians(),
            pivot_distance: self.pivot_distance,
            lateral_sigma: self.lateral_sigma,
        }
    }

    /// Checks ranges; errors name the key under `pose`.
    pub fn validate(&self) -> Result<()> {
        let bad = |k: &str, m: &str| Err(Error::config(k, m));
        for (k, v) in [("pose.max_pitch_deg", self.max_pitch_deg), ("pose.max_yaw_deg", self.max_yaw_deg)] {
            if !(0.0..=90.0).contains(&v) {
                return bad(k, "must be 0..=90 degrees");
            }
        }
        if !(self.pivot_distance.is_finite() && self.pivot_distance >= 0.0 && self.pivot_distance < 100.0) {
            return bad("pose.pivot_distance", "must be 0..100 metres");
        }
        if !(self.lateral_sigma.is_finite() && self.lateral_sigma >= 0.0 && self.lateral_sigma < 10.0) {
            return bad("pose.lateral_sigma", "must be 0..10 metres");
        }
        if let Some(t) = &self.target {
            let e = &t.bin_edges;
            if e.len() < 2 || e.windows(2).any(|w| !(w[0] < w[1])) || e[0] < 0.0 || e[e.len() - 1] > 1.0 {
                return bad("pose.target.bin_edges", "must be at least two increasing values in [0, 1]");
            }
            let w = &t.weights;
            if w.len() != e.len() - 1 || w.iter().any(|w| !(*w >= 0.0 && w.is_finite())) || w.iter().sum::<f64>() <= 0.0 {
                return bad("pose.target.weights", "needs one non-negative weight per bin (edges - 1), not all zero");
            }
            if t.max_draws == 0 || t.max_draws > 10_000 {
                return bad("pose.target.max_draws", "must be 1..=10000");
            }
        }
        Ok(())
    }

    /// The stage. Overlap estimates ([`OverlapTarget`]) see the views and clouds as the later stages make
    /// them: corrected by `condition` (the condition correction), cut to the working depth range and crop
    /// box, voxelized at `voxel` (the voxelize stage's), compared at `radius` (the validate stage's).
    /// Without a target, nothing is estimated (and no corrector is built).
    pub fn build(&self, condition: &CorrectionConfig, depth_range: DepthRange, crop_box: AxisBox, voxel: f32, radius: f32) -> PoseSampling {
        let target = self.target.clone().map(|t| {
            (t, OverlapEstimate { condition: condition.build(), range: depth_range, crop_box, voxel, radius })
        });
        PoseSampling { sampler: self.pivot_sampler(), target }
    }
}

/// How [`sample_towards_bin`] estimates the overlap a pose gives: what the later stages do to the view
/// and the clouds.
pub struct OverlapEstimate {
    /// The condition correction (it drops re-projected pixels before the fill).
    pub condition: Box<dyn Corrector>,
    /// The working depth range and crop box (both clouds are cut to them in their own camera frames).
    pub range: DepthRange,
    pub crop_box: AxisBox,
    /// The voxel of the stored clouds, metres.
    pub voxel: f32,
    /// The overlap radius of the validate stage, metres.
    pub radius: f32,
}

impl OverlapEstimate {
    /// The estimated `overlap_source` of a pose: `memory` (full-resolution source points) z-buffered into
    /// the target camera, corrected, and its [`view_overlap`] with `probes` (`memory` voxelized at
    /// [`Self::voxel`]).
    pub fn of(&self, probes: &[Point], memory: &[Point], pose: &Isometry3<f64>, k: &Intrinsics) -> f64 {
        let proj = project_zbuffer(memory, pose, k, false);
        let (mut view, mut known) = (proj.depth, proj.known);
        correct_condition(self.condition.as_ref(), None, &mut view, &mut known);
        view_overlap(probes, &view, pose, k, self.range, &self.crop_box, self.voxel, self.radius)
    }
}

/// Draws `T_target_from_source` from the unit's seed.
pub struct PoseSampling {
    pub sampler: PivotPoseSampler,
    /// The overlap histogram to steer towards, and how overlaps are estimated.
    pub target: Option<(OverlapTarget, OverlapEstimate)>,
}

impl Stage<PairUnit> for PoseSampling {
    fn name(&self) -> &'static str {
        "pose"
    }

    fn process(&mut self, unit: &mut PairUnit) -> Result<()> {
        let mut rng = Rng::new(unit.seed).fork(streams::POSE);
        let (pose, draws) = match &self.target {
            None => (self.sampler.sample(&mut rng), 1),
            Some((t, estimate)) => {
                let k = unit.k.expect("ingest sets the intrinsics");
                sample_towards_bin(&self.sampler, t, &unit.source_points, &unit.memory, &k, estimate, &mut rng)
            }
        };
        unit.t_target_from_source = pose;
        unit.pose_draws = draws;
        Ok(())
    }
}

/// The bin a unit is assigned: drawn by `target.weights` from the unit's pose stream (its first draw).
pub fn assigned_bin(target: &OverlapTarget, rng: &mut Rng) -> usize {
    let total: f64 = target.weights.iter().sum();
    let mut pick = rng.uniform() * total;
    for (i, w) in target.weights.iter().enumerate() {
        if pick < *w {
            return i;
        }
        pick -= w;
    }
    target.weights.len() - 1
}

/// Picks the unit's bin ([`assigned_bin`]), then draws poses until the estimated overlap of `memory` (the
/// source points in the crop box, full resolution; `probes`: `memory` voxelized at `estimate.voxel`, i.e.
/// the source cloud ingest made) falls in it, adapting the motion scale after each miss;
/// after `max_draws` keeps the draw closest to the bin. Returns the pose and the number of draws.
pub fn sample_towards_bin(
    sampler: &PivotPoseSampler,
    target: &OverlapTarget,
    probes: &[Point],
    memory: &[Point],
    k: &Intrinsics,
    estimate: &OverlapEstimate,
    rng: &mut Rng,
) -> (Isometry3<f64>, u32) {
    let bin = assigned_bin(target, rng);
    let (lo, hi) = (target.bin_edges[bin], target.bin_edges[bin + 1]);
    let mut best = (f64::INFINITY, Isometry3::identity());
    let mut scale = 1.0;
    for draw in 1..=target.max_draws {
        let pose = sampler.scaled(scale).sample(rng);
        let c = estimate.of(probes, memory, &pose, k);
        if c >= lo && c < hi {
            return (pose, draw);
        }
        let distance = if c < lo { lo - c } else { c - hi };
        if distance < best.0 {
            best = (distance, pose);
        }
        scale = if c >= hi { scale * SCALE_STEP } else { scale / SCALE_STEP }.clamp(SCALE_RANGE.0, SCALE_RANGE.1);
    }
    (best.1, target.max_draws)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::voxel_downsample;

    #[test]
    fn draws_land_in_the_assigned_bin_and_the_histogram_follows_the_weights() {
        // A plane 2 m ahead, seen by the official sampler: its overlap rarely drops below 0.5 at the official
        // motion, so the low bin needs the widened draws.
        let k = Intrinsics::new(150.0, 150.0, 63.5, 63.5, 128, 128).unwrap();
        let memory: Vec<Point> = (0..128 * 128).map(|i| Point::new(((i % 128) as f32 - 63.5) * 2.0 / 150.0, ((i / 128) as f32 - 63.5) * 2.0 / 150.0, 2.0)).collect();
        let target = OverlapTarget { bin_edges: vec![0.1, 0.5, 0.9], weights: vec![1.0, 3.0], max_draws: 200 };
        let sampler = PivotPoseSampler::default();
        let condition = Box::new(crate::correction::NoCorrection);
        let estimate = OverlapEstimate { condition, range: DepthRange::OFFICIAL, crop_box: AxisBox::OFFICIAL, voxel: 0.025, radius: 0.0375 };
        let probes = voxel_downsample(&memory, estimate.voxel);
        let mut counts = [0usize; 2];
        for s in 0..400u64 {
            let mut rng = Rng::new(s);
            let (pose, draws) = sample_towards_bin(&sampler, &target, &probes, &memory, &k, &estimate, &mut rng);
            let c = estimate.of(&probes, &memory, &pose, &k);
            assert!(draws < 200, "unit {s} never reached its bin");
            assert!((0.1..0.9).contains(&c));
            counts[if c < 0.5 { 0 } else { 1 }] += 1;
        }
        let share = counts[1] as f64 / 400.0;
        assert!((share - 0.75).abs() < 0.07, "bin shares {counts:?}");
    }

    #[test]
    fn bad_targets_are_refused_naming_the_key() {
        let mut c = PoseConfig::default();
        c.validate().unwrap();
        c.target = Some(OverlapTarget { bin_edges: vec![0.5, 0.2], weights: vec![1.0], max_draws: 4 });
        assert!(c.validate().unwrap_err().to_string().contains("pose.target.bin_edges"));
        c.target = Some(OverlapTarget { bin_edges: vec![0.1, 0.3, 1.0], weights: vec![1.0], max_draws: 4 });
        assert!(c.validate().unwrap_err().to_string().contains("pose.target.weights"));
        c.target = None;
        c.max_yaw_deg = 120.0;
        assert!(c.validate().unwrap_err().to_string().contains("pose.max_yaw_deg"));
    }
}
