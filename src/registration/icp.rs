//! Point-to-point ICP refinement (Besl & McKay): nearest target point within a distance, Kabsch, repeat.

use super::kdtree::KdTree;
use super::ransac::kabsch;
use crate::geometry::Point;
use nalgebra::{Isometry3, Vector3};
use rayon::prelude::*;

/// Refines `init` (`t_target_from_source`) for at most `iterations` rounds, pairing each moved source
/// point with its nearest target point closer than `distance`; stops when the pose moves less than 1e-7.
pub fn icp_point_to_point(
    source: &[Point],
    target: &KdTree,
    target_points: &[Point],
    init: &Isometry3<f64>,
    distance: f32,
    iterations: usize,
) -> Isometry3<f64> {
    let mut pose = *init;
    for _ in 0..iterations {
        let pf = pose.cast::<f32>();
        let pairs: Vec<(Vector3<f64>, Vector3<f64>)> = source
            .par_iter()
            .filter_map(|p| {
                let q = pf * p;
                let mut out = Vec::with_capacity(1);
                target.search(&[q.x, q.y, q.z], 1, distance * distance, &mut out);
                out.first().map(|&(j, _)| (p.coords.cast::<f64>(), target_points[j as usize].coords.cast::<f64>()))
            })
            .collect();
        let (s, t): (Vec<_>, Vec<_>) = pairs.into_iter().unzip();
        let Some(next) = kabsch(&s, &t) else { break };
        let step = next * pose.inverse();
        pose = next;
        if step.translation.vector.norm() < 1e-7 && step.rotation.angle() < 1e-7 {
            break;
        }
    }
    pose
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn converges_from_a_small_offset() {
        // A bumpy sphere (Fibonacci points, radius 1 ± 0.2): every degree of freedom is constrained.
        let pts: Vec<Point> = (0..2000)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f32 + 0.5) / 2000.0;
                let (rho, phi) = ((1.0 - z * z).sqrt(), i as f32 * 2.399_963);
                let r = 1.0 + 0.2 * (3.0 * z).sin() * (2.0 * phi).cos();
                Point::new(r * rho * phi.cos(), r * rho * phi.sin(), r * z + 3.0)
            })
            .collect();
        let truth = Isometry3::new(Vector3::new(0.01, -0.02, 0.015), Vector3::new(0.01, 0.02, -0.01));
        let tgt: Vec<Point> = pts.iter().map(|p| truth.cast::<f32>() * p).collect();
        let tree = KdTree::from_points(&tgt);
        let est = icp_point_to_point(&pts, &tree, &tgt, &Isometry3::identity(), 0.1, 60);
        let d = est.inverse() * truth;
        assert!(d.translation.vector.norm() < 1e-3 && d.rotation.angle() < 1e-3, "{d:?}");
    }
}
