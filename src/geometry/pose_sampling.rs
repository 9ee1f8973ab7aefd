//! The official pose sampler: the new camera orbits a pivot ahead of the source camera.

use crate::rng::Rng;
use nalgebra::{Isometry3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Reference §2: `θ ~ U(±max_pitch)` about camera x, `φ ~ U(±max_yaw)` about camera y, no roll,
/// `R = Rx(θ)·Ry(φ)`, pivot `c = (0, 0, pivot_distance)`, `t = c − R·c + n` with
/// `n = (N(0, σ²), N(0, σ²), 0)`. The result is `T_target_from_source` (`p' = R·p + t`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PivotPoseSampler {
    /// Largest rotation about the camera x axis, radians (official π/24 = 7.5°).
    pub max_pitch: f64,
    /// Largest rotation about the camera y axis, radians (official π/12 = 15°).
    pub max_yaw: f64,
    /// Distance of the pivot ahead of the source camera, metres (official 3).
    pub pivot_distance: f64,
    /// Standard deviation of the lateral x/y jitter, metres (official 1/3).
    pub lateral_sigma: f64,
}

impl Default for PivotPoseSampler {
    fn default() -> Self {
        PivotPoseSampler {
            max_pitch: std::f64::consts::PI / 24.0,
            max_yaw: std::f64::consts::PI / 12.0,
            pivot_distance: 3.0,
            lateral_sigma: 1.0 / 3.0,
        }
    }
}

impl PivotPoseSampler {
    /// The sampler with its motion scaled by `s`: both angle bounds (capped at 90°) and the lateral
    /// standard deviation times `s`, the pivot unchanged.
    pub fn scaled(&self, s: f64) -> PivotPoseSampler {
        let cap = std::f64::consts::FRAC_PI_2;
        PivotPoseSampler {
            max_pitch: (self.max_pitch * s).min(cap),
            max_yaw: (self.max_yaw * s).min(cap),
            pivot_distance: self.pivot_distance,
            lateral_sigma: self.lateral_sigma * s,
        }
    }

    /// Draws `T_target_from_source`; uses exactly four draws of `rng` (θ, φ, n_x, n_y).
    pub fn sample(&self, rng: &mut Rng) -> Isometry3<f64> {
        let theta = rng.uniform_range(-self.max_pitch, self.max_pitch);
        let phi = rng.uniform_range(-self.max_yaw, self.max_yaw);
        let nx = rng.normal() * self.lateral_sigma;
        let ny = rng.normal() * self.lateral_sigma;
        let r = Rotation3::from_axis_angle(&Vector3::x_axis(), theta) * Rotation3::from_axis_angle(&Vector3::y_axis(), phi);
        let c = Vector3::new(0.0, 0.0, self.pivot_distance);
        let t = c - r * c + Vector3::new(nx, ny, 0.0);
        Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_rotation_matrix(&r))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn statistics_match_the_reference_monte_carlo() {
        // Reference §2: mean rotation 8.9°, max ≈ 16.7°, mean translation 0.62 m, median 0.59 m.
        let s = PivotPoseSampler::default();
        let mut rng = Rng::new(2024);
        let n = 20_000;
        let mut angles = Vec::with_capacity(n);
        let mut norms = Vec::with_capacity(n);
        for _ in 0..n {
            let t = s.sample(&mut rng);
            angles.push(t.rotation.angle().to_degrees());
            norms.push(t.translation.vector.norm());
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        norms.sort_by(f64::total_cmp);
        assert!((mean(&angles) - 8.9).abs() < 0.2, "mean angle {}", mean(&angles));
        assert!(angles.iter().cloned().fold(0.0, f64::max) < 16.8);
        assert!((mean(&norms) - 0.62).abs() < 0.02, "mean translation {}", mean(&norms));
        assert!((norms[n / 2] - 0.59).abs() < 0.02, "median translation {}", norms[n / 2]);
    }

    #[test]
    fn pivot_is_fixed_without_jitter() {
        let s = PivotPoseSampler { lateral_sigma: 0.0, ..Default::default() };
        let t = s.sample(&mut Rng::new(1));
        let pivot = nalgebra::Point3::new(0.0, 0.0, 3.0);
        assert!((t * pivot - pivot).norm() < 1e-12);
    }
}
