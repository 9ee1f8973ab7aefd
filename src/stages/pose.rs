//! Pose sampling: the official pivot sampler, optionally redrawn towards a target overlap histogram.

use super::{streams, PairUnit};
use crate::error::Result;
use crate::geometry::{AxisBox, DepthRange, Intrinsics, PivotPoseSampler, Point};
use crate::pipeline::config::OverlapTarget;
use crate::rng::Rng;
use crate::runtime::Stage;
use nalgebra::Isometry3;

/// Draws `T_target_from_source` from the unit's seed.
pub struct PoseSampling {
    pub sampler: PivotPoseSampler,
    pub target: Option<OverlapTarget>,
    pub depth_range: DepthRange,
    pub crop_box: AxisBox,
}

impl Stage<PairUnit> for PoseSampling {
    fn name(&self) -> &'static str {
        "pose"
    }

    fn process(&mut self, unit: &mut PairUnit) -> Result<()> {
        let mut rng = Rng::new(unit.seed).fork(streams::POSE);
        let (pose, draws) = match &self.target {
            None => (self.sampler.sample(&mut rng), 1),
            Some(t) => {
                let k = unit.k.expect("ingest sets the intrinsics");
                sample_towards_bin(&self.sampler, t, &unit.memory, &k, self.depth_range, &self.crop_box, &mut rng)
            }
        };
        unit.t_target_from_source = pose;
        unit.pose_draws = draws;
        Ok(())
    }
}

/// Picks the unit's bin (weighted by `target.weights`), then draws poses until [`coverage`] falls in it;
/// after `max_draws` keeps the draw closest to the bin. Returns the pose and the number of draws.
pub fn sample_towards_bin(
    sampler: &PivotPoseSampler,
    target: &OverlapTarget,
    memory: &[Point],
    k: &Intrinsics,
    range: DepthRange,
    crop_box: &AxisBox,
    rng: &mut Rng,
) -> (Isometry3<f64>, u32) {
    let total: f64 = target.weights.iter().sum();
    let mut pick = rng.uniform() * total;
    let mut bin = target.weights.len() - 1;
    for (i, w) in target.weights.iter().enumerate() {
        if pick < *w {
            bin = i;
            break;
        }
        pick -= w;
    }
    let (lo, hi) = (target.bin_edges[bin], target.bin_edges[bin + 1]);
    let mut best = (f64::INFINITY, Isometry3::identity());
    for draw in 1..=target.max_draws {
        let pose = sampler.sample(rng);
        let c = coverage(memory, &pose, k, range, crop_box);
        if c >= lo && c < hi {
            return (pose, draw);
        }
        let distance = if c < lo { lo - c } else { c - hi };
        if distance < best.0 {
            best = (distance, pose);
        }
    }
    (best.1, target.max_draws)
}

/// Cheap overlap estimate: the fraction of (every 16th) memory point that lands inside the target
/// image, inside the depth range and inside the target's crop box.
pub fn coverage(memory: &[Point], t_target_from_source: &Isometry3<f64>, k: &Intrinsics, range: DepthRange, crop_box: &AxisBox) -> f64 {
    let (mut seen, mut total) = (0usize, 0usize);
    for p in memory.iter().step_by(16) {
        total += 1;
        let q = t_target_from_source * nalgebra::Point3::new(p.x as f64, p.y as f64, p.z as f64);
        let qf = Point::new(q.x as f32, q.y as f32, q.z as f32);
        if !range.contains(qf.z) || !crop_box.contains(&qf) {
            continue;
        }
        let u = (q.x * k.fx / q.z + k.cx).round_ties_even();
        let v = (q.y * k.fy / q.z + k.cy).round_ties_even();
        if u >= 0.0 && v >= 0.0 && u < k.width as f64 && v < k.height as f64 {
            seen += 1;
        }
    }
    if total == 0 {
        0.0
    } else {
        seen as f64 / total as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_land_in_the_assigned_bin_and_the_histogram_follows_the_weights() {
        // A plane 2 m ahead: coverage falls with the lateral jitter, so every bin is reachable.
        let k = Intrinsics::new(150.0, 150.0, 63.5, 63.5, 128, 128).unwrap();
        let memory: Vec<Point> = (0..128 * 128).map(|i| Point::new(((i % 128) as f32 - 63.5) * 2.0 / 150.0, ((i / 128) as f32 - 63.5) * 2.0 / 150.0, 2.0)).collect();
        let target = OverlapTarget { bin_edges: vec![0.1, 0.5, 0.9], weights: vec![1.0, 3.0], max_draws: 200 };
        let sampler = PivotPoseSampler { lateral_sigma: 1.0, ..Default::default() };
        let mut counts = [0usize; 2];
        for s in 0..400u64 {
            let mut rng = Rng::new(s);
            let (pose, draws) = sample_towards_bin(&sampler, &target, &memory, &k, DepthRange::OFFICIAL, &AxisBox::OFFICIAL, &mut rng);
            let c = coverage(&memory, &pose, &k, DepthRange::OFFICIAL, &AxisBox::OFFICIAL);
            assert!(draws < 200, "unit {s} never reached its bin");
            assert!((0.1..0.9).contains(&c));
            counts[if c < 0.5 { 0 } else { 1 }] += 1;
        }
        let share = counts[1] as f64 / 400.0;
        assert!((share - 0.75).abs() < 0.07, "bin shares {counts:?}");
    }
}
