//! A Kinect-v1-like depth sensor model: axial noise growing with depth (Nguyen et al. 2012), dropouts
//! at grazing incidence and at depth discontinuities, speckle dropouts, quantisation and range limits.

use super::render::Render;
use crate::error::{Error, Result};
use crate::geometry::DepthMap;
use crate::rng::Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Parameters of the noise model. The defaults describe a Kinect v1 / PrimeSense sensor.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorConfig {
    /// Nearest measurable depth, metres; nearer readings become 0 (invalid).
    pub min_depth_m: f64,
    /// Farthest measurable depth, metres; farther readings become 0.
    pub max_depth_m: f64,
    /// Constant term of the axial noise σ(z) = base + quadratic·(z − offset)², metres.
    pub noise_base_m: f64,
    /// Quadratic coefficient of σ(z), metres of σ per square metre of (z − offset)², i.e. 1/m.
    pub noise_quadratic_per_m: f64,
    /// Depth at which σ(z) is smallest, metres.
    pub noise_offset_m: f64,
    /// Incidence angle (between the viewing ray and the surface normal), degrees, from which
    /// readings start to drop out; the drop probability rises linearly to 1 at `grazing_full_deg`.
    pub grazing_start_deg: f64,
    /// Incidence angle, degrees, at and beyond which every reading drops out.
    pub grazing_full_deg: f64,
    /// A pixel sits on a depth discontinuity when a 4-neighbour's true depth differs from its own by
    /// more than this fraction of its own depth (unitless; 0.05 = 5 cm at 1 m), or has no depth.
    pub edge_jump_fraction: f64,
    /// Probability (0–1) that a pixel on a discontinuity reads 0.
    pub edge_drop_probability: f64,
    /// Probability (0–1) that any other pixel reads 0 (speckle dropouts).
    pub speckle_drop_probability: f64,
    /// Quantisation step of the output, metres (1 mm: the units of the 16-bit PNGs).
    pub quantization_m: f64,
}

impl Default for SensorConfig {
    fn default() -> Self {
        SensorConfig {
            min_depth_m: 0.4,
            max_depth_m: 8.0,
            noise_base_m: 0.0012,
            noise_quadratic_per_m: 0.0019,
            noise_offset_m: 0.4,
            grazing_start_deg: 70.0,
            grazing_full_deg: 82.0,
            edge_jump_fraction: 0.05,
            edge_drop_probability: 0.6,
            speckle_drop_probability: 0.002,
            quantization_m: 0.001,
        }
    }
}

impl SensorConfig {
    /// A sensor that only quantises to 1 mm (no noise, no dropouts, range 0–65 m).
    pub fn ideal() -> Self {
        SensorConfig {
            min_depth_m: 0.0,
            max_depth_m: 65.0,
            noise_base_m: 0.0,
            noise_quadratic_per_m: 0.0,
            grazing_start_deg: 90.0,
            grazing_full_deg: 90.0,
            edge_drop_probability: 0.0,
            speckle_drop_probability: 0.0,
            ..SensorConfig::default()
        }
    }

    /// Axial noise standard deviation at depth `z`, both in metres.
    pub fn sigma(&self, z: f64) -> f64 {
        self.noise_base_m + self.noise_quadratic_per_m * (z - self.noise_offset_m).powi(2)
    }

    /// Checks the fields: finite, ordered, probabilities in [0, 1], step positive.
    pub fn validate(&self) -> Result<()> {
        let bad = |f: &str, m: &str| Err(Error::config(f, m.to_string()));
        if !(self.min_depth_m >= 0.0 && self.min_depth_m < self.max_depth_m && self.max_depth_m <= 65.0) {
            return bad("max_depth_m", "needs 0 <= min_depth_m < max_depth_m <= 65 m");
        }
        if !(self.noise_base_m >= 0.0 && self.noise_quadratic_per_m >= 0.0 && self.noise_offset_m.is_finite()) {
            return bad("noise_base_m", "noise coefficients must be finite and non-negative");
        }
        if !(0.0 <= self.grazing_start_deg && self.grazing_start_deg <= self.grazing_full_deg && self.grazing_full_deg <= 90.0) {
            return bad("grazing_full_deg", "needs 0 <= grazing_start_deg <= grazing_full_deg <= 90");
        }
        for (f, p) in [("edge_drop_probability", self.edge_drop_probability), ("speckle_drop_probability", self.speckle_drop_probability)] {
            if !(0.0..=1.0).contains(&p) {
                return bad(f, "must lie in [0, 1]");
            }
        }
        if !(self.edge_jump_fraction > 0.0 && self.edge_jump_fraction.is_finite()) {
            return bad("edge_jump_fraction", "must be positive");
        }
        if !(self.quantization_m >= 1e-4 && self.quantization_m <= 0.1) {
            return bad("quantization_m", "must lie in [0.0001, 0.1] m");
        }
        Ok(())
    }

    /// Probability that a reading with incidence cosine `cos` drops out for its angle alone.
    fn grazing_drop(&self, cos: f64) -> f64 {
        let angle = cos.clamp(0.0, 1.0).acos().to_degrees();
        if angle >= self.grazing_full_deg {
            1.0
        } else if angle <= self.grazing_start_deg {
            0.0
        } else {
            (angle - self.grazing_start_deg) / (self.grazing_full_deg - self.grazing_start_deg)
        }
    }

    /// The sensor's reading of the noise-free view `truth`: depth in metres, multiples of the
    /// quantisation step, 0 where dropped or out of range. Every random draw comes from
    /// `Rng::new(seed).fork(row)`, two per pixel whatever happens, so the result depends on the
    /// seed alone and not on the thread count.
    pub fn apply(&self, truth: &Render, seed: u64) -> DepthMap {
        let d = &truth.depth;
        let (w, h) = (d.width() as usize, d.height() as usize);
        let z = d.data();
        let base = Rng::new(seed);
        let mut out = vec![0.0f32; w * h];
        out.par_chunks_mut(w).enumerate().for_each(|(r, row)| {
            let mut rng = base.fork(r as u64);
            for (c, o) in row.iter_mut().enumerate() {
                let (u, n) = (rng.uniform(), rng.normal());
                let i = r * w + c;
                let zt = z[i] as f64;
                if zt <= 0.0 {
                    continue;
                }
                let jump = |j: usize| {
                    let zn = z[j] as f64;
                    zn <= 0.0 || (zn - zt).abs() > self.edge_jump_fraction * zt
                };
                let edge = (c > 0 && jump(i - 1))
                    || (c + 1 < w && jump(i + 1))
                    || (r > 0 && jump(i - w))
                    || (r + 1 < h && jump(i + w));
                let keep_edge = if edge { 1.0 - self.edge_drop_probability } else { 1.0 - self.speckle_drop_probability };
                let keep = keep_edge * (1.0 - self.grazing_drop(truth.cos_incidence[i] as f64));
                if u >= keep {
                    continue;
                }
                let noisy = zt + self.sigma(zt) * n;
                let q = (noisy / self.quantization_m).round() * self.quantization_m;
                // Exactly the value a millimetre PNG decodes to: round to whole mm, divide in f32.
                let zq = (q * 1000.0).round() as f32 / 1000.0;
                if (zq as f64) >= self.min_depth_m && (zq as f64) <= self.max_depth_m && zq > 0.0 {
                    *o = zq;
                }
            }
        });
        DepthMap::new(d.width(), d.height(), out).expect("finite non-negative depth")
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Scene, Shape};
    use super::*;
    use crate::geometry::Intrinsics;
    use nalgebra::{Isometry3, Point3, Vector3};

    fn k() -> Intrinsics {
        Intrinsics::new(585.0, 585.0, 320.0, 240.0, 640, 480).unwrap()
    }

    fn wall_at(z: f64) -> Render {
        let scene = Scene::from_shapes(vec![Shape::Plane { point: Point3::new(0.0, 0.0, z), normal: Vector3::z() }]);
        scene.render(&k(), &Isometry3::identity())
    }

    #[test]
    fn noise_on_a_frontal_wall_has_the_kinect_sigma_and_whole_millimetres() {
        let s = SensorConfig::default();
        for (z, seed) in [(1.0f64, 1u64), (3.0, 2)] {
            let out = s.apply(&wall_at(z), seed);
            let e: Vec<f64> = out.data().iter().filter(|v| **v > 0.0).map(|v| *v as f64 - z).collect();
            assert!(e.len() > 640 * 480 * 99 / 100, "frontal wall keeps nearly every pixel: {}", e.len());
            let mean = e.iter().sum::<f64>() / e.len() as f64;
            let std = (e.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / e.len() as f64).sqrt();
            let expect = 0.0012 + 0.0019 * (z - 0.4).powi(2);
            assert!((std / expect - 1.0).abs() < 0.15, "z = {z}: std {std} vs sigma {expect}");
            assert!(mean.abs() < 0.1 * expect, "z = {z}: bias {mean}");
            for v in out.data() {
                let mm = *v as f64 * 1000.0;
                assert!((mm - mm.round()).abs() < 1e-3, "{v} is not a whole millimetre");
            }
        }
        assert_eq!(s.apply(&wall_at(0.3), 1).valid_count(), 0, "nearer than the minimum range");
        assert_eq!(s.apply(&wall_at(9.0), 1).valid_count(), 0, "beyond the maximum range");
    }

    #[test]
    fn grazing_floor_pixels_drop_out_and_frontal_ones_stay() {
        // Camera 0.3 m above a floor (y down in the camera frame), a wall 6 m ahead.
        let scene = Scene::from_shapes(vec![
            Shape::Plane { point: Point3::new(0.0, 0.3, 0.0), normal: Vector3::y() },
            Shape::Plane { point: Point3::new(0.0, 0.0, 6.0), normal: Vector3::z() },
        ]);
        let truth = scene.render(&k(), &Isometry3::identity());
        let out = SensorConfig::default().apply(&truth, 9);
        let (mut grazing, mut grazing_dropped, mut frontal, mut frontal_dropped, mut beyond_full) = (0, 0, 0, 0, 0);
        for (i, (&cos, &z)) in truth.cos_incidence.iter().zip(out.data()).enumerate() {
            let angle = (cos as f64).acos().to_degrees();
            let t = truth.depth.data()[i];
            if !(0.5..7.5).contains(&t) {
                continue;
            }
            if angle > 75.0 {
                grazing += 1;
                grazing_dropped += usize::from(z == 0.0);
                beyond_full += usize::from(angle > 82.5 && z > 0.0);
            } else if angle < 40.0 {
                frontal += 1;
                frontal_dropped += usize::from(z == 0.0);
            }
        }
        let (g, f) = (grazing_dropped as f64 / grazing as f64, frontal_dropped as f64 / frontal as f64);
        assert!(grazing > 5000 && frontal > 50000, "{grazing} {frontal}");
        assert!(g > 0.6 && f < 0.02, "dropped: grazing {g}, frontal {f}");
        assert_eq!(beyond_full, 0);
    }

    #[test]
    fn depth_edges_drop_out_at_the_configured_rate() {
        let scene = Scene::from_shapes(vec![
            Shape::Plane { point: Point3::new(0.0, 0.0, 3.0), normal: Vector3::z() },
            Shape::Sphere { center: Point3::new(0.0, 0.0, 1.5), radius: 0.4 },
        ]);
        let truth = scene.render(&k(), &Isometry3::identity());
        let s = SensorConfig { speckle_drop_probability: 0.0, grazing_start_deg: 90.0, grazing_full_deg: 90.0, ..SensorConfig::default() };
        let out = s.apply(&truth, 4);
        let z = truth.depth.data();
        let (mut edge, mut edge_dropped, mut inner_dropped) = (0, 0, 0);
        for r in 1..479 {
            for c in 1..639 {
                let i = r * 640 + c;
                let jump = [i - 1, i + 1, i - 640, i + 640].iter().any(|&j| (z[j] - z[i]).abs() > 0.05 * z[i]);
                if jump {
                    edge += 1;
                    edge_dropped += usize::from(out.data()[i] == 0.0);
                } else {
                    inner_dropped += usize::from(out.data()[i] == 0.0);
                }
            }
        }
        let rate = edge_dropped as f64 / edge as f64;
        assert!(edge > 1000 && (rate - 0.6).abs() < 0.06, "{edge} edge pixels, drop rate {rate}");
        assert_eq!(inner_dropped, 0);
    }

    #[test]
    fn same_seed_same_reading_other_seed_other_reading() {
        let s = SensorConfig::default();
        let truth = wall_at(2.0);
        assert_eq!(s.apply(&truth, 5), s.apply(&truth, 5));
        assert_ne!(s.apply(&truth, 5), s.apply(&truth, 6));
        let ideal = SensorConfig::ideal().apply(&truth, 5);
        assert!(ideal.data().iter().all(|&v| v == 2.0));
        assert!(SensorConfig { min_depth_m: 9.0, ..s.clone() }.validate().is_err());
        assert!(SensorConfig { edge_drop_probability: -0.1, ..s }.validate().is_err());
    }
}
