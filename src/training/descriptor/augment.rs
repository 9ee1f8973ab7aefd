//! The augmentation registration trainers apply each time a pair is drawn (GeoTransformer's and PREDATOR's
//! 3DMatch loaders: Gaussian noise on the points, a random rotation), and dropping the filled target
//! points of generated pairs (the positives rule is [`super::data::may_be_positive`]).

use super::data::{TrainPair, KNOWN_MIN_SHARE};
use crate::geometry::Point;
use crate::rng::Rng;
use nalgebra::{Isometry3, Translation3, Unit, UnitQuaternion, Vector3};
use serde::Serialize;

/// How a pair is perturbed each time a training step draws it.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Augment {
    /// Gaussian noise added to every coordinate of both clouds, σ in metres (0: none).
    pub noise_m: f32,
    /// Each cloud turned by its own random rotation, about a uniformly random axis by an angle uniform in
    /// `[0, rotation_deg]` degrees (0: none); the pose follows, so it still maps source onto target.
    pub rotation_deg: f64,
}

impl Augment {
    pub fn is_off(&self) -> bool {
        self.noise_m == 0.0 && self.rotation_deg == 0.0
    }

    /// `pair` perturbed with draws from `rng`: `p_s' = R_s p_s + n`, `p_t' = R_t p_t + n'`,
    /// `T' = R_t · T · R_s⁻¹` (noise n, n' ~ N(0, σ²) per coordinate).
    pub fn apply(&self, pair: &TrainPair, rng: &mut Rng) -> TrainPair {
        let (rs, rt) = (self.rotation(rng), self.rotation(rng));
        let source = self.moved(&pair.source, &rs, rng);
        let target = self.moved(&pair.target, &rt, rng);
        TrainPair {
            key: pair.key.clone(),
            source,
            target,
            target_observed: pair.target_observed.clone(),
            real: pair.real,
            t_target_from_source: rt * pair.t_target_from_source * rs.inverse(),
        }
    }

    fn rotation(&self, rng: &mut Rng) -> Isometry3<f64> {
        if self.rotation_deg == 0.0 {
            return Isometry3::identity();
        }
        // A uniform axis: a normalised Gaussian vector.
        let axis = loop {
            let v = Vector3::new(rng.normal(), rng.normal(), rng.normal());
            if v.norm() > 1e-9 {
                break Unit::new_normalize(v);
            }
        };
        let angle = rng.uniform() * self.rotation_deg.to_radians();
        Isometry3::from_parts(Translation3::identity(), UnitQuaternion::from_axis_angle(&axis, angle))
    }

    fn moved(&self, cloud: &[Point], r: &Isometry3<f64>, rng: &mut Rng) -> Vec<Point> {
        let r = r.cast::<f32>();
        let mut noise = vec![0f32; if self.noise_m > 0.0 { 3 * cloud.len() } else { 0 }];
        rng.fill_normal_f32(&mut noise);
        cloud
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let q = r * p;
                match noise.get(3 * i..3 * i + 3) {
                    Some(n) => Point::new(q.x + self.noise_m * n[0], q.y + self.noise_m * n[1], q.z + self.noise_m * n[2]),
                    None => q,
                }
            })
            .collect()
    }
}

/// `pair` without its made-up target points (those whose observed share, re-projected or seen by the scene,
/// is below [`KNOWN_MIN_SHARE`]), so they appear in no local frame, patch or feature; a pair without
/// provenance is unchanged.
pub fn drop_filled(pair: &TrainPair) -> TrainPair {
    if pair.target_observed.len() != pair.target.len() {
        return pair.clone();
    }
    let (target, target_observed) =
        pair.target.iter().zip(&pair.target_observed).filter(|(_, &s)| s >= KNOWN_MIN_SHARE).map(|(p, s)| (*p, *s)).unzip();
    TrainPair { target, target_observed, ..pair.clone() }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pair() -> TrainPair {
        let mut rng = Rng::new(1);
        let source: Vec<Point> = (0..4000).map(|_| Point::new(rng.uniform() as f32, rng.uniform() as f32, 1.0 + rng.uniform() as f32)).collect();
        let t = Isometry3::from_parts(Translation3::new(0.1, 0.0, -0.2), UnitQuaternion::from_euler_angles(0.2, -0.1, 0.3));
        let target: Vec<Point> = source.iter().map(|p| t.cast::<f32>() * p).collect();
        let target_observed = (0..target.len()).map(|i| if i % 4 == 0 { 0.0 } else { 1.0 }).collect();
        TrainPair { key: "k".into(), source, target, target_observed, real: false, t_target_from_source: t }
    }

    #[test]
    fn noise_is_applied_with_the_asked_spread() {
        let p = pair();
        let a = Augment { noise_m: 0.01, rotation_deg: 0.0 };
        let q = a.apply(&p, &mut Rng::new(7));
        let d: Vec<f64> = p.source.iter().zip(&q.source).flat_map(|(a, b)| [(b.x - a.x) as f64, (b.y - a.y) as f64, (b.z - a.z) as f64]).collect();
        let mean = d.iter().sum::<f64>() / d.len() as f64;
        let sd = (d.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / d.len() as f64).sqrt();
        assert!(mean.abs() < 0.0005 && (sd - 0.01).abs() < 0.0005, "mean {mean}, sd {sd}");
        assert!(q.target.iter().zip(&p.target).any(|(a, b)| a != b), "the target is noised too");
        assert_eq!(q.t_target_from_source, p.t_target_from_source, "noise leaves the pose");
        // Off: the same pair.
        let off = Augment::default().apply(&p, &mut Rng::new(7));
        assert_eq!((off.source, off.target), (p.source.clone(), p.target.clone()));
    }

    #[test]
    fn rotation_keeps_the_pose_consistent() {
        let p = pair();
        let q = Augment { noise_m: 0.0, rotation_deg: 180.0 }.apply(&p, &mut Rng::new(3));
        assert!((q.source[0] - p.source[0]).norm() > 0.01, "the source was turned");
        let t = q.t_target_from_source.cast::<f32>();
        let worst = q.source.iter().zip(&q.target).map(|(s, tp)| (t * s - tp).norm()).fold(0f32, f32::max);
        assert!(worst < 1e-4, "the new pose maps the turned source onto the turned target (worst {worst} m)");
    }

    #[test]
    fn dropping_filled_points() {
        let p = pair();
        let real = TrainPair { target_observed: Vec::new(), real: true, ..p.clone() };
        let d = drop_filled(&p);
        assert_eq!(d.target.len(), 3000);
        assert!(d.target_observed.iter().all(|&s| s >= KNOWN_MIN_SHARE));
        assert_eq!(drop_filled(&real).target.len(), 4000);
    }
}
