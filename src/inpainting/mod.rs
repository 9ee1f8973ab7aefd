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

    /// One re-projection of a synthetic scene, the setting the fills work in: the source view rendered
    /// exactly at the working resolution, back-projected, z-buffered into a target pose the official
    /// sampler draws, and the scene's exact depth from that target pose (the oracle).
    struct Reprojection {
        /// The re-projected depth (0 at unknown pixels, as the pipeline hands it to the fill).
        condition: DepthMap,
        known: Vec<bool>,
        /// The source view's own depth, pixel for pixel: stale values a pass-through would leak.
        source: DepthMap,
        truth: DepthMap,
        /// Unknown pixels whose true surface lies in the working range and inside the source camera's field
        /// of view: disocclusions and re-projection cracks, not extrapolation beyond what the source saw.
        hidden: Vec<usize>,
        ctx: InpaintContext,
    }

    fn reprojection(scene_seed: u64, pose_seed: u64) -> Reprojection {
        use crate::geometry::{backproject, project_zbuffer, DepthRange, PivotPoseSampler, ResizeCrop};
        use crate::sources::synthetic::{SyntheticConfig, SyntheticSequence, DEFAULT_INTRINSICS};
        use nalgebra::Point3;
        let seq = SyntheticSequence::generate(&SyntheticConfig { frames: 1, ..Default::default() }, scene_seed).unwrap();
        let k = ResizeCrop::official(640, 480, 128).unwrap().official_intrinsics(&DEFAULT_INTRINSICS).unwrap();
        let t_world_from_source = seq.poses[0];
        let source = seq.scene.render_depth(&k, &t_world_from_source);
        let t_target_from_source = PivotPoseSampler::default().sample(&mut Rng::new(pose_seed));
        let proj = project_zbuffer(&backproject(&source, &k, DepthRange::OFFICIAL), &t_target_from_source, &k, false);
        let truth = seq.scene.render_depth(&k, &(t_world_from_source * t_target_from_source.inverse()));
        let (w, h) = (k.width as usize, k.height as usize);
        let t_source_from_target = t_target_from_source.inverse();
        let hidden = (0..w * h)
            .filter(|&i| {
                let z = truth.data()[i] as f64;
                if proj.known[i] || !DepthRange::OFFICIAL.contains(z as f32) {
                    return false;
                }
                let (c, r) = ((i % w) as f64, (i / w) as f64);
                let p = t_source_from_target * Point3::new((c - k.cx) / k.fx * z, (r - k.cy) / k.fy * z, z);
                let (u, v) = (p.x / p.z * k.fx + k.cx, p.y / p.z * k.fy + k.cy);
                p.z > 0.0 && u >= -0.5 && v >= -0.5 && u < w as f64 - 0.5 && v < h as f64 - 0.5
            })
            .collect();
        let ctx = InpaintContext { intrinsics: k, seed: 0, t_target_from_source };
        Reprojection { condition: proj.depth, known: proj.known, source, truth, hidden, ctx }
    }

    /// Absolute errors (metres) of `filled` against the truth at the hidden pixels, sorted; a pixel left
    /// at 0 counts its whole true depth.
    fn hidden_errors(case: &Reprojection, filled: &[f32]) -> Vec<f32> {
        let mut e: Vec<f32> = case.hidden.iter().map(|&i| (filled[i] - case.truth.data()[i]).abs()).collect();
        e.sort_by(f32::total_cmp);
        e
    }

    /// Share of the hidden pixels a fill must bring within [`CLOSE_M`] of the true depth, pooled over the
    /// cases of [`classical_fills_recover_the_true_hidden_depth_and_a_constant_or_pass_through_does_not`].
    const MIN_CLOSE_SHARE: f64 = 0.45;
    const CLOSE_M: f32 = 0.05;

    /// The scene's exact depth is the oracle: every classical fill must bring at least 45% of the hidden
    /// pixels within 5 cm of the truth (pooled over six scenes, each re-projected into a pose the official
    /// sampler draws, at 128×128), and three controls computed here must not: a constant fill (the mean
    /// of the known depths), the pass-through of the input the pipeline hands over (unknown pixels are 0)
    /// and the pass-through of stale input (unknown pixels holding the source view's own depth at that
    /// pixel). Each fill also runs on the stale input, and must give the same map.
    ///
    /// Measured (share within 5 cm pooled over the six cases, and pooled median error): background 0.862
    /// (4 mm), nearest 0.821 (11 mm), push–pull 0.717 (9 mm), IP-Basic 0.647 (34 mm; per case ≥ 0.53); the
    /// controls: constant 0.115 (190 mm; per case ≤ 0.19), stale pass-through 0.168 (222 mm; per case
    /// ≤ 0.41), zero pass-through 0 (2.27 m). The bound, 0.45, lies about 0.2 below the weakest fill and
    /// 0.28 above the strongest control. Holes are mostly re-projection cracks and disocclusions; a
    /// mean-absolute-error bound would not separate (IP-Basic's and the constant's are both ≈ 0.16 m on
    /// one scene: a few wrong-surface pixels weigh as much as many good ones), so the bound counts close
    /// pixels.
    #[test]
    fn classical_fills_recover_the_true_hidden_depth_and_a_constant_or_pass_through_does_not() {
        let cases: Vec<Reprojection> = [(1u64, 11u64), (2, 12), (3, 13), (4, 14), (5, 15), (6, 16)].iter().map(|&(s, p)| reprojection(s, p)).collect();
        for (i, case) in cases.iter().enumerate() {
            assert!(case.hidden.len() > 500, "case {i}: only {} hidden pixels", case.hidden.len());
        }
        let stale_inputs: Vec<DepthMap> = cases
            .iter()
            .map(|case| {
                let mut d = case.condition.clone();
                for (i, z) in d.data_mut().iter_mut().enumerate() {
                    if !case.known[i] {
                        *z = case.source.data()[i];
                    }
                }
                d
            })
            .collect();
        // Share of all hidden pixels within CLOSE_M, and the pooled median error, of one fill per case.
        let score = |filled: &[Vec<f32>]| {
            let mut e: Vec<f32> = cases.iter().zip(filled).flat_map(|(case, f)| hidden_errors(case, f)).collect();
            e.sort_by(f32::total_cmp);
            (e.iter().filter(|x| **x <= CLOSE_M).count() as f64 / e.len() as f64, e[e.len() / 2])
        };

        let constant: Vec<Vec<f32>> = cases
            .iter()
            .map(|case| {
                let d = case.condition.data();
                let known_z: Vec<f64> = (0..d.len()).filter(|&i| case.known[i] && d[i] > 0.0).map(|i| d[i] as f64).collect();
                let mean = (known_z.iter().sum::<f64>() / known_z.len() as f64) as f32;
                (0..d.len()).map(|i| if case.known[i] { d[i] } else { mean }).collect()
            })
            .collect();
        let zero: Vec<Vec<f32>> = cases.iter().map(|c| c.condition.data().to_vec()).collect();
        let stale: Vec<Vec<f32>> = stale_inputs.iter().map(|d| d.data().to_vec()).collect();
        for (name, filled) in [("constant (mean of the known depths)", &constant), ("pass-through of 0", &zero), ("pass-through of stale input", &stale)] {
            let (close, median) = score(filled);
            println!("control {name}: {close:.3} within {CLOSE_M} m, median error {median:.3} m");
            assert!(close < MIN_CLOSE_SHARE, "the control {name} meets the bound ({close:.3} within {CLOSE_M} m): the test cannot tell it from a fill");
        }

        for m in classical().into_iter().filter(|m| m.name() != "none") {
            let on_zero: Vec<Vec<f32>> = cases.iter().map(|c| m.inpaint(&c.condition, &c.known, &c.ctx).into_data()).collect();
            let on_stale: Vec<Vec<f32>> = cases.iter().zip(&stale_inputs).map(|(c, d)| m.inpaint(d, &c.known, &c.ctx).into_data()).collect();
            for (input, filled) in [("0 at unknown pixels", &on_zero), ("stale depth at unknown pixels", &on_stale)] {
                let (close, median) = score(filled);
                println!("{} on {input}: {close:.3} within {CLOSE_M} m, median error {median:.3} m", m.name());
                assert!(
                    close >= MIN_CLOSE_SHARE,
                    "{} on {input}: only {close:.3} of the hidden pixels within {CLOSE_M} m of the true depth (median error {median:.3} m), want at least {MIN_CLOSE_SHARE}",
                    m.name()
                );
            }
            for (i, (a, b)) in on_zero.iter().zip(&on_stale).enumerate() {
                assert!(a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()), "{}: case {i} depends on the values at unknown pixels", m.name());
            }
        }
    }

    #[test]
    fn classical_fills_stay_within_the_known_depths() {
        // A range property on random depths (every pixel filled, nothing outside the known depths), not a
        // quality check: a constant fill passes it; the synthetic-scene test above checks the quality.
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
