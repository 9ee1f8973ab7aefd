//! Re-projection holes for hole-aware fine-tuning (`train diffusion --holes`).
//!
//! A build samples the denoiser from the push–pull fill of a re-projected view, noised to a small step.
//! A network trained only on Gaussian-noised clean frames never sees that input: a smooth fill spanning
//! the holes a camera move opens. Here a training frame gets such holes with its true depth still known:
//! its points are projected into a camera moved by a (scaled) draw of the build's pivot sampler and back,
//! so the pixels the moved camera could not see — disocclusions, the strip outside its frustum, the
//! cracks of forward projection — are unknown, as in a re-projected view, and the rest keep the
//! round trip's depth. A corrector then drops pixels as the build's `[correct.condition]` does, and the
//! sampler's classical start (push–pull or background) fills the unknown pixels.

use crate::correction::{apply_keep_mask, Corrector};
use crate::geometry::{backproject, project_zbuffer, DepthMap, DepthRange, Intrinsics, PivotPoseSampler};
use crate::inpainting::{InpaintContext, Inpainter};
use crate::nn::space::{from_network, to_network, DEPTH_SCALE_M};
use crate::rng::Rng;
use nalgebra::Isometry3;

/// A view of a depth map after a round trip through another camera.
#[derive(Clone, Debug, PartialEq)]
pub struct RoundTrip {
    /// Depth where some point came back (0 elsewhere), metres.
    pub depth: DepthMap,
    /// Pixels some point came back to.
    pub known: Vec<bool>,
}

/// Projects the points of `depth` (camera `k`, depths in (0, 10 m), the network's range) into the camera
/// `t_moved_from_camera`, back-projects what that camera sees and projects it back into `k`.
pub fn round_trip(depth: &DepthMap, k: &Intrinsics, t_moved_from_camera: &Isometry3<f64>) -> RoundTrip {
    let range = DepthRange { near: 0.0, far: DEPTH_SCALE_M };
    let moved = project_zbuffer(&backproject(depth, k, range), t_moved_from_camera, k, false);
    let back = project_zbuffer(&backproject(&moved.depth, k, range), &t_moved_from_camera.inverse(), k, false);
    RoundTrip { depth: back.depth, known: back.known }
}

/// The camera move of one training frame: the pivot sampler with its angles and jitter scaled by a
/// uniform draw in [`MOTION_SCALE`], from consecutive-frame motion up to the build's full motion.
pub fn sample_motion(sampler: &PivotPoseSampler, rng: &mut Rng) -> Isometry3<f64> {
    let s = rng.uniform_range(MOTION_SCALE.0, MOTION_SCALE.1);
    sampler.scaled(s).sample(rng)
}

/// Range of the motion scale of [`sample_motion`].
pub const MOTION_SCALE: (f64, f64) = (0.1, 1.0);

/// The keep thresholds (τ_m) of the correction U-Net among the corrections of hole-aware training
/// (`train diffusion --holes-correction`): the demo's and the official one.
pub const UNET_THRESHOLDS: [f32; 2] = [0.5, 0.99];

/// One holed training frame in network space: the sampler's start (the round trip's known depths with
/// the classical fill in the holes) and the holes (pixels unknown after the round trip and the correction).
pub struct HoledFrame {
    pub start: Vec<f32>,
    pub holes: Vec<bool>,
}

/// Opens holes in a network-space frame (row-major `width`×`height`, intrinsics `[fx, fy, cx, cy]`) by a
/// round trip through `t_moved_from_camera` and `correct`, and fills them with `fill` as the sampler's
/// classical start does. The re-projected view comes from the moved camera, so the fill is told the
/// motion `t_target_from_source = inv(t_moved_from_camera)` (the epipolar direction of `Background`).
pub fn holed_frame(
    frame: &[f32],
    width: usize,
    height: usize,
    intrinsics: [f64; 4],
    t_moved_from_camera: &Isometry3<f64>,
    correct: &dyn Corrector,
    fill: &dyn Inpainter,
) -> HoledFrame {
    let [fx, fy, cx, cy] = intrinsics;
    let k = Intrinsics::new(fx, fy, cx, cy, width as u32, height as u32).expect("training intrinsics are valid");
    let depth = DepthMap::new(width as u32, height as u32, frame.iter().map(|v| from_network(*v)).collect()).expect("frame size");
    let RoundTrip { mut depth, mut known } = round_trip(&depth, &k, t_moved_from_camera);
    let keep = correct.keep_mask(&depth);
    apply_keep_mask(&mut depth, &mut known, &keep);
    let filled = fill.inpaint(&depth, &known, &InpaintContext { intrinsics: k, seed: 0, t_target_from_source: t_moved_from_camera.inverse() });
    HoledFrame { start: filled.data().iter().map(|z| to_network(*z)).collect(), holes: known.iter().map(|k| !k).collect() }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::correction::{CorrectionConfig, NoCorrection};
    use crate::inpainting::{Background, PushPull};
    use nalgebra::{Translation3, UnitQuaternion};

    const W: u32 = 64;

    fn k() -> Intrinsics {
        Intrinsics::new(50.0, 50.0, 31.5, 31.5, W, W).unwrap()
    }

    #[test]
    fn identity_round_trip_keeps_every_pixel_with_depth() {
        // A slanted plane with a missing patch: nothing moves, so only the missing pixels are unknown.
        let data: Vec<f32> =
            (0..W * W).map(|i| if (i % W) < 5 && (i / W) < 5 { 0.0 } else { 2.0 + 0.01 * (i % W) as f32 }).collect();
        let depth = DepthMap::new(W, W, data.clone()).unwrap();
        let trip = round_trip(&depth, &k(), &Isometry3::identity());
        for (i, z) in data.iter().enumerate() {
            assert_eq!(trip.known[i], *z > 0.0, "pixel {i}");
            if *z > 0.0 {
                assert!((trip.depth.data()[i] - z).abs() < 1e-5, "pixel {i}: {} vs {z}", trip.depth.data()[i]);
            }
        }
    }

    #[test]
    fn a_sideways_move_hides_the_strip_the_moved_camera_cannot_see() {
        // A wall at 2 m, camera moved 0.4 m to +x: points land fx·0.4/2 = 10 columns further left, so the
        // 10 leftmost columns of the original view leave the moved camera's frustum and come back unknown.
        let depth = DepthMap::new(W, W, vec![2.0; (W * W) as usize]).unwrap();
        let t = Isometry3::from_parts(Translation3::new(-0.4, 0.0, 0.0), UnitQuaternion::identity());
        let trip = round_trip(&depth, &k(), &t);
        for r in 0..W as usize {
            for c in 0..W as usize {
                assert_eq!(trip.known[r * W as usize + c], c >= 10, "pixel ({c}, {r})");
            }
        }
    }

    #[test]
    fn a_move_behind_a_box_opens_its_shadow_and_push_pull_fills_it() {
        // A box 1 m away in front of a wall at 3 m; moving the camera sideways hides the wall behind the
        // box's edge from the moved camera: a band of wall next to the box comes back unknown.
        let (w, wall, near) = (W as usize, 3.0f32, 1.0f32);
        let data: Vec<f32> = (0..w * w).map(|i| if (20..44).contains(&(i % w)) && (20..44).contains(&(i / w)) { near } else { wall }).collect();
        let frame: Vec<f32> = data.iter().map(|z| to_network(*z)).collect();
        let t = Isometry3::from_parts(Translation3::new(-0.1, 0.0, 0.0), UnitQuaternion::identity());
        let holed = holed_frame(&frame, w, w, k().as_vector(), &t, &NoCorrection, &PushPull);
        // Moving 0.1 m to +x shifts the box 5 px left and the wall 1.7 px: the wall just left of the box,
        // columns 17..20 of rows inside the box (column c lands at round(c − 1.67), the box at 15..=38),
        // is behind the box from the moved camera; column 16 lands at 14, beside it.
        let row = 32;
        assert!(!holed.holes[row * w + 16]);
        for c in 17..20 {
            assert!(holed.holes[row * w + c], "column {c} should be a hole");
        }
        assert!(!holed.holes[row * w + 30] && !holed.holes[row * w + 50]);
        // Every hole gets a depth between the nearest and farthest known depth.
        for (i, h) in holed.holes.iter().enumerate() {
            let z = from_network(holed.start[i]);
            if *h {
                assert!(z >= near - 1e-3 && z <= wall + 1e-3, "pixel {i}: {z}");
            } else {
                assert!((z - data[i]).abs() < 1e-3, "known pixel {i}: {z}");
            }
        }
    }

    #[test]
    fn a_background_start_fills_the_boxs_shadow_with_the_wall() {
        // The scene above: the shadow next to the box is wall that the moved camera could not see. The
        // background fill copies the farther border along the motion (the wall, 3 m) where push–pull
        // blends it with the box (1 m) into depths on neither surface.
        let (w, wall, near) = (W as usize, 3.0f32, 1.0f32);
        let data: Vec<f32> = (0..w * w).map(|i| if (20..44).contains(&(i % w)) && (20..44).contains(&(i / w)) { near } else { wall }).collect();
        let frame: Vec<f32> = data.iter().map(|z| to_network(*z)).collect();
        let t = Isometry3::from_parts(Translation3::new(-0.1, 0.0, 0.0), UnitQuaternion::identity());
        let background = holed_frame(&frame, w, w, k().as_vector(), &t, &NoCorrection, &Background);
        let push_pull = holed_frame(&frame, w, w, k().as_vector(), &t, &NoCorrection, &PushPull);
        assert_eq!(background.holes, push_pull.holes, "the holes do not depend on the fill");
        let row = 32;
        for c in 17..20 {
            let i = row * w + c;
            assert!((from_network(background.start[i]) - wall).abs() < 1e-3, "column {c}: {}", from_network(background.start[i]));
            assert!(from_network(push_pull.start[i]) < wall - 0.05, "push-pull blends column {c}");
        }
        for (i, h) in background.holes.iter().enumerate() {
            if !h {
                assert_eq!(background.start[i], push_pull.start[i], "known pixel {i} is kept as it is");
            }
        }
    }

    #[test]
    fn the_corrector_drops_pixels_into_the_holes() {
        // A wall with one pixel 20 cm behind it (a penetration, as a re-projection can leave): the official
        // min-pool filter drops it, so it is a hole; without correction it is not.
        let w = W as usize;
        let mut data = vec![to_network(2.0); w * w];
        data[32 * w + 32] = to_network(2.2);
        let none = holed_frame(&data, w, w, k().as_vector(), &Isometry3::identity(), &NoCorrection, &PushPull);
        let min_pool = holed_frame(&data, w, w, k().as_vector(), &Isometry3::identity(), &*CorrectionConfig::OFFICIAL_MIN_POOL.build(), &PushPull);
        assert!(!none.holes.iter().any(|h| *h));
        assert_eq!(min_pool.holes.iter().filter(|h| **h).count(), 1);
        assert!(min_pool.holes[32 * w + 32]);
        assert!((from_network(min_pool.start[32 * w + 32]) - 2.0).abs() < 1e-4, "push-pull fills it from the wall");
    }

    #[test]
    fn scaled_motion_stays_within_the_samplers_bounds() {
        let s = PivotPoseSampler::default();
        let mut rng = Rng::new(7);
        let bound = (s.max_pitch.powi(2) + s.max_yaw.powi(2)).sqrt();
        let angles: Vec<f64> = (0..2000).map(|_| sample_motion(&s, &mut rng).rotation.angle()).collect();
        assert!(angles.iter().all(|a| *a <= bound + 1e-9));
        let mean = angles.iter().sum::<f64>() / angles.len() as f64;
        // Full motion averages 8.9° (reference §2); a scale uniform in [0.1, 1] averages 0.55 of it.
        assert!((mean.to_degrees() - 8.9 * 0.55).abs() < 0.5, "mean {}", mean.to_degrees());
    }
}
