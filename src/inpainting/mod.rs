//! Inpainting: fill the pixels the re-projection left unknown, keeping known pixels bit-exact. Methods:
//! none, the classical fills — push–pull ([`push_pull`]), nearest valid pixel ([`nearest`]), IP-Basic's
//! morphological completion ([`ip_basic`], a peer) and the occlusion-aware background fill along the
//! epipolar direction ([`background`]) — and the diffusion model
//! with the range–null-space step ([`diffusion`]); [`config`] names them in pipeline configs.

pub mod background;
pub mod config;
pub mod diffusion;
pub mod ip_basic;
pub mod nearest;
pub mod push_pull;

use crate::geometry::{DepthMap, Intrinsics};
use nalgebra::Isometry3;

pub use config::InpaintConfig;
pub use diffusion::{DiffusionInpaintConfig, DiffusionInpainter, Start};
pub use background::Background;
pub use ip_basic::IpBasic;
pub use nearest::Nearest;
pub use push_pull::PushPull;

/// What an inpainter may know about a target view besides its pixels.
#[derive(Clone, Copy, Debug)]
pub struct InpaintContext {
    /// The target camera's working-resolution intrinsics.
    pub intrinsics: Intrinsics,
    /// The work unit's seed: every random draw of a stochastic method comes from it.
    pub seed: u64,
    /// The pose of the target camera relative to the camera the condition was re-projected from (identity
    /// when unknown): its translation gives the epipolar direction along which disocclusions open.
    pub t_target_from_source: Isometry3<f64>,
}

/// A depth inpainting method.
pub trait Inpainter: Send + Sync {
    /// Short name recorded in provenance.
    fn name(&self) -> &'static str;
    /// A full depth map whose known pixels equal `depth` bit for bit and whose unknown pixels are filled
    /// (or left 0 where the method cannot fill).
    fn inpaint(&self, depth: &DepthMap, known: &[bool], ctx: &InpaintContext) -> DepthMap;
    /// How many views [`Inpainter::inpaint_batch`] fills together at best (1: one at a time).
    fn batch(&self) -> usize {
        1
    }
    /// Fills several views; each result is what [`Inpainter::inpaint`] gives for that view alone.
    fn inpaint_batch(&self, views: &[(&DepthMap, &[bool], &InpaintContext)]) -> Vec<DepthMap> {
        views.iter().map(|(d, known, ctx)| self.inpaint(d, known, ctx)).collect()
    }
}

/// Leaves unknown pixels empty.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoInpainting;

impl Inpainter for NoInpainting {
    fn name(&self) -> &'static str {
        "none"
    }
    fn inpaint(&self, depth: &DepthMap, known: &[bool], _: &InpaintContext) -> DepthMap {
        let mut out = depth.clone();
        for (z, k) in out.data_mut().iter_mut().zip(known) {
            if !k {
                *z = 0.0;
            }
        }
        out
    }
}

/// A context for unit tests of inpainters: a pinhole camera centred on the map, seed 0.
#[cfg(test)]
pub(crate) fn test_context(d: &DepthMap) -> InpaintContext {
    let (w, h) = (d.width(), d.height());
    InpaintContext {
        intrinsics: Intrinsics::new(w as f64, w as f64, w as f64 / 2.0, h as f64 / 2.0, w, h).unwrap(),
        seed: 0,
        t_target_from_source: Isometry3::identity(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use nalgebra::{Translation3, UnitQuaternion};

    /// Every classical method, as the config names them.
    fn classical() -> Vec<Box<dyn Inpainter>> {
        [InpaintConfig::None {}, InpaintConfig::PushPull {}, InpaintConfig::Nearest {}, InpaintConfig::Background {}, InpaintConfig::IpBasic {}]
            .iter()
            .map(|c| c.build().unwrap())
            .collect()
    }

    #[test]
    fn every_classical_method_keeps_known_pixels_bit_for_bit_and_is_deterministic() {
        let mut r = Rng::new(5);
        for case in 0..12 {
            let (w, h) = (8 + r.below(40) as u32, 8 + r.below(40) as u32);
            let share = r.uniform();
            // Known pixels include zeros (known but empty, e.g. after a correction) and odd bit patterns.
            let data: Vec<f32> = (0..w * h)
                .map(|_| if r.uniform() < 0.1 { 0.0 } else { r.uniform_range(0.3, 9.0) as f32 + f32::EPSILON })
                .collect();
            let known: Vec<bool> = (0..w * h).map(|_| r.uniform() < share).collect();
            let d = DepthMap::new(w, h, data.clone()).unwrap();
            let mut ctx = test_context(&d);
            let move_ = Translation3::new(r.uniform_range(-0.3, 0.3), r.uniform_range(-0.3, 0.3), r.uniform_range(-0.3, 0.3));
            ctx.t_target_from_source = Isometry3::from_parts(move_, UnitQuaternion::from_euler_angles(0.1, -0.05, 0.02));
            for m in classical() {
                let a = m.inpaint(&d, &known, &ctx);
                let b = m.inpaint(&d, &known, &ctx);
                assert_eq!((a.width(), a.height()), (w, h));
                for i in 0..(w * h) as usize {
                    if known[i] {
                        assert_eq!(a.data()[i].to_bits(), data[i].to_bits(), "{} case {case} pixel {i}", m.name());
                    }
                    assert_eq!(a.data()[i].to_bits(), b.data()[i].to_bits(), "{} is not deterministic", m.name());
                }
            }
        }
    }

    #[test]
    fn classical_fills_stay_within_the_known_depths() {
        // Nearest copies known depths; background copies or interpolates two of them; push–pull and
        // IP-Basic average them.
        let mut r = Rng::new(9);
        let (w, h) = (40u32, 30u32);
        let data: Vec<f32> = (0..w * h).map(|_| r.uniform_range(0.5, 5.0) as f32).collect();
        let known: Vec<bool> = (0..w * h).map(|_| r.uniform() < 0.2).collect();
        let d = DepthMap::new(w, h, data.clone()).unwrap();
        let mut ctx = test_context(&d);
        ctx.t_target_from_source = Isometry3::translation(0.1, 0.05, 0.0);
        let pool: Vec<u32> = (0..data.len()).filter(|i| known[*i]).map(|i| data[i].to_bits()).collect();
        let nearest = InpaintConfig::Nearest {}.build().unwrap().inpaint(&d, &known, &ctx);
        assert!(nearest.data().iter().all(|z| pool.contains(&z.to_bits())));
        let (lo, hi) = pool.iter().map(|b| f32::from_bits(*b)).fold((f32::MAX, 0.0f32), |(l, h), z| (l.min(z), h.max(z)));
        // With a known pixel every 5 on average, every pixel is in reach of each fill (IP-Basic's
        // dilations included: it leaves 0 only farther than 15 pixels from known depth), so each fills
        // every pixel, with a depth within the known ones.
        for m in [InpaintConfig::Background {}, InpaintConfig::PushPull {}, InpaintConfig::IpBasic {}] {
            let out = m.build().unwrap().inpaint(&d, &known, &ctx);
            for (i, z) in out.data().iter().enumerate() {
                assert!(*z >= lo - 1e-5 && *z <= hi + 1e-5, "{m:?}: pixel {i} is {z}, outside the known depths [{lo}, {hi}]");
            }
        }
    }
}
