//! The official 3DMatch metrics: inlier ratio, feature-match recall, the registration error with the
//! information matrix (and recall), RRE / RTE, and the information matrix of a pair.
//!
//! Poses: `t_gt` and `t_est` both map the source (fragment j) into the target (fragment i).

use crate::geometry::Point;
use nalgebra::{Isometry3, Matrix6, Vector6};

/// A correspondence is an inlier when its residual under the ground truth is below this, metres.
pub const INLIER_DISTANCE: f32 = 0.10;
/// A pair counts for FMR when its inlier ratio is above this.
pub const FMR_INLIER_RATIO: f64 = 0.05;
/// A pair is registered when its error (`xᵀ·Info·x / Info₀₀`) is at most this (0.2 m squared).
pub const RR_ERROR: f64 = 0.2 * 0.2;

/// Fraction of `corr` (source index, target index) whose source point, moved by `t_gt`, lies within
/// [`INLIER_DISTANCE`] of its target point; 0 for no correspondences.
pub fn inlier_ratio(source: &[Point], target: &[Point], corr: &[(u32, u32)], t_gt: &Isometry3<f64>) -> f64 {
    if corr.is_empty() {
        return 0.0;
    }
    let t = t_gt.cast::<f32>();
    let r2 = INLIER_DISTANCE * INLIER_DISTANCE;
    let n = corr.iter().filter(|&&(i, j)| (t * source[i as usize] - target[j as usize]).norm_squared() < r2).count();
    n as f64 / corr.len() as f64
}

/// The official registration error: `x = [t, q_xyz]` of `Δ = inv(t_gt)·t_est` (quaternion with w ≥ 0),
/// `xᵀ·info·x / info₀₀`. The pair is registered when this is at most [`RR_ERROR`].
pub fn registration_error(t_gt: &Isometry3<f64>, t_est: &Isometry3<f64>, info: &Matrix6<f64>) -> f64 {
    let d = t_gt.inverse() * t_est;
    let q = d.rotation.quaternion();
    let s = if q.w < 0.0 { -1.0 } else { 1.0 };
    let t = d.translation.vector;
    let x = Vector6::new(t.x, t.y, t.z, s * q.i, s * q.j, s * q.k);
    (x.transpose() * info * x)[(0, 0)] / info[(0, 0)]
}

/// Relative rotation error in degrees and translation error in metres of `t_est` against `t_gt`.
pub fn rre_rte(t_gt: &Isometry3<f64>, t_est: &Isometry3<f64>) -> (f64, f64) {
    let dr = t_gt.rotation.inverse() * t_est.rotation;
    (dr.angle().to_degrees(), (t_gt.translation.vector - t_est.translation.vector).norm())
}

/// The information matrix of a pair from the source points `p` (in the source frame) that overlap the
/// target: `Σ Gᵀ·G` with `G = [I | −2·[p]×]`, so that for a small `Δ`, `xᵀ·Info·x` is the summed squared
/// displacement of those points (`q_xyz ≈ ω/2`) and `xᵀ·Info·x / Info₀₀` their mean (Choi et al. 2015).
pub fn information_matrix(points: &[Point]) -> Matrix6<f64> {
    let mut info = Matrix6::zeros();
    for p in points {
        let (x, y, z) = (p.x as f64, p.y as f64, p.z as f64);
        #[rustfmt::skip]
        let g = nalgebra::Matrix3x6::new(
            1.0, 0.0, 0.0, 0.0, 2.0 * z, -2.0 * y,
            0.0, 1.0, 0.0, -2.0 * z, 0.0, 2.0 * x,
            0.0, 0.0, 1.0, 2.0 * y, -2.0 * x, 0.0,
        );
        info += g.transpose() * g;
    }
    info
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn small_error_is_the_mean_squared_displacement() {
        let pts: Vec<Point> = (0..50)
            .map(|i| Point::new((i % 5) as f32 * 0.3, (i / 5) as f32 * 0.2 - 1.0, 2.0 + (i % 3) as f32 * 0.1))
            .collect();
        let info = information_matrix(&pts);
        let gt = Isometry3::new(Vector3::new(1.0, 0.0, 0.5), Vector3::new(0.0, 0.3, 0.0));
        let delta = Isometry3::new(Vector3::new(0.01, -0.02, 0.005), Vector3::new(0.004, 0.002, -0.003));
        let est = gt * delta;
        let msd: f64 = pts
            .iter()
            .map(|p| {
                let p = p.cast::<f64>();
                (delta * p - p).norm_squared()
            })
            .sum::<f64>()
            / pts.len() as f64;
        let e = registration_error(&gt, &est, &info);
        assert!((e - msd).abs() < 1e-3 * msd, "{e} vs {msd}");
    }
}
