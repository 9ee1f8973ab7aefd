//! Background fill along the epipolar direction: the holes of a re-projection are mostly disocclusions,
//! surfaces the source camera could not see behind a foreground edge. Along the epipolar line through a
//! hole pixel (the line on which the camera motion moves every image point), one border of the hole is the
//! occluding foreground and the other the uncovered background; the fill copies the farther border. The
//! motion uncovers only one side: nearer points move farther along [`epipolar_direction`], so the
//! foreground of a disocclusion is its border on the `+direction` side. A hole whose farther border lies on
//! that side was not opened by the motion (a sensor gap, a penetration mask), and the fill copies the
//! nearest known pixel there. When both borders lie on one surface (depths within [`SAME_SURFACE_REL`]),
//! the hole is a crack or a sensor gap rather than a disocclusion, and the fill interpolates linearly
//! between them instead.

use super::nearest::nearest_source_indices;
use super::{InpaintContext, Inpainter};
use crate::geometry::{DepthMap, Intrinsics};
use nalgebra::Isometry3;
use rayon::prelude::*;

/// Two hole borders whose depths differ by at most this share of the nearer are one surface.
pub const SAME_SURFACE_REL: f32 = 0.05;

/// Fills each unknown pixel from the two nearest known depths along its epipolar line: the farther one
/// when it lies on the side the motion uncovers (the `−direction` side), their linear interpolation when
/// both are one surface, the one found when the other side leaves the image. Where the farther border lies
/// on the `+direction` side, the motion gives no direction (no translation, or the pixel at the epipole) or
/// no border is found, the nearest known pixel is copied.
#[derive(Clone, Copy, Debug, Default)]
pub struct Background;

impl Inpainter for Background {
    fn name(&self) -> &'static str {
        "background"
    }

    fn inpaint(&self, depth: &DepthMap, known: &[bool], ctx: &InpaintContext) -> DepthMap {
        let (w, h) = (depth.width() as usize, depth.height() as usize);
        let d = depth.data();
        let sources: Vec<bool> = d.iter().zip(known).map(|(z, k)| *k && *z > 0.0).collect();
        let epipole = epipole(&ctx.intrinsics, &ctx.t_target_from_source);
        let nearest = nearest_source_indices(&sources, w, h);
        let free = clearance(&nearest, w);
        // Rows in parallel (each pixel's fill depends only on the input); `None`: no border found.
        let borders: Vec<Option<f32>> = (0..h)
            .into_par_iter()
            .flat_map_iter(|r| (0..w).map(move |c| (r, c)))
            .map(|(r, c)| {
                let j = r * w + c;
                if known[j] {
                    return Some(d[j]);
                }
                let (c, r) = (c as f64, r as f64);
                let (dx, dy) = epipolar_direction(epipole, c, r)?;
                let walk = |dx, dy| first_source(&sources, &free, w, h, c, r, dx, dy);
                match (walk(dx, dy), walk(-dx, -dy)) {
                    (Some((a, na)), Some((b, nb))) => {
                        // a: the border where nearer points land (the foreground of a disocclusion).
                        let (za, zb) = (d[a], d[b]);
                        if (za - zb).abs() <= SAME_SURFACE_REL * za.min(zb) {
                            // Steps na and nb away on either side: weights by the distance to the other.
                            Some((za * nb as f32 + zb * na as f32) / (na + nb) as f32)
                        } else if zb > za {
                            Some(zb)
                        } else {
                            // Farther on the side the motion covers: not a disocclusion; nearest pixel.
                            None
                        }
                    }
                    (a, b) => a.or(b).map(|(i, _)| d[i]),
                }
            })
            .collect();
        let out: Vec<f32> = borders
            .iter()
            .enumerate()
            .map(|(j, b)| match b {
                Some(z) => *z,
                None => nearest[j].map_or(0.0, |i| d[i]),
            })
            .collect();
        DepthMap::new(depth.width(), depth.height(), out).expect("copies of valid depths are valid")
    }
}

/// The source camera's centre projected into the target image, homogeneous `(x, y, w)` in pixels
/// (`w = 0`: the epipole is at infinity and every epipolar line is parallel to `(x, y)`).
pub fn epipole(k: &Intrinsics, t_target_from_source: &Isometry3<f64>) -> [f64; 3] {
    let t = t_target_from_source.translation.vector;
    [k.fx * t.x + k.cx * t.z, k.fy * t.y + k.cy * t.z, t.z]
}

/// The epipolar direction at pixel `(c, r)`, scaled so its larger component is 1 (one pixel per step), or
/// `None` when the motion gives none. It points where nearer points land: a source point at depth `z`
/// whose ray projects to `m` at infinite depth lands at `p = λ·m + (1 − λ)·ε`, with `ε` the epipole and
/// `λ = z·a₃ / (z·a₃ + e₃)` (`a₃ > 0` the depth of the rotated ray). Going nearer (smaller `z`) moves `p`
/// from `m` along `e − m·e₃` (toward `ε` when `e₃ > 0`, away from it when `e₃ < 0`; along `(e₀, e₁)` when
/// `e₃ = 0`), which is the `(e₀ − c·e₂, e₁ − r·e₂)` below.
fn epipolar_direction(e: [f64; 3], c: f64, r: f64) -> Option<(f64, f64)> {
    let (dx, dy) = (e[0] - c * e[2], e[1] - r * e[2]);
    let m = dx.abs().max(dy.abs());
    // Below a thousandth of a pixel per metre of scene the direction is rounding noise.
    (m > 1e-3).then(|| (dx / m, dy / m))
}

/// Each pixel's distance to its nearest source pixel (∞ without one): no source lies closer.
fn clearance(nearest: &[Option<usize>], w: usize) -> Vec<f32> {
    (0..nearest.len())
        .map(|j| {
            nearest[j].map_or(f32::INFINITY, |i| {
                let (dr, dc) = ((i / w) as f32 - (j / w) as f32, (i % w) as f32 - (j % w) as f32);
                (dr * dr + dc * dc).sqrt()
            })
        })
        .collect()
}

/// The first source pixel met walking from `(c, r)` in steps of `(dx, dy)` before leaving the image (the
/// pixel nearest to each step), and the number of steps. `free` (see [`clearance`]) only speeds it up:
/// from a pixel with no source within `D`, the next `⌊(D − 1.5)/|step|⌋` steps land on pixels within
/// `D − 1.5 + 2·(√2/2) < D` of it, so they are skipped; the result is the plain walk's.
#[allow(clippy::too_many_arguments)]
fn first_source(sources: &[bool], free: &[f32], w: usize, h: usize, c: f64, r: f64, dx: f64, dy: f64) -> Option<(usize, u32)> {
    let (wl, hl) = (w as f64 - 0.5, h as f64 - 0.5);
    let step = (dx * dx + dy * dy).sqrt();
    let mut i = 1u32;
    loop {
        let (x, y) = (c + i as f64 * dx, r + i as f64 * dy);
        // round(x) in 0..w, i.e. x in (−0.5, w − 0.5); then round(x) = floor(x + 0.5) = (x + 0.5) as usize.
        // The image is convex: a walk that is outside after a skip left it on a skipped (sourceless) step.
        if x <= -0.5 || y <= -0.5 || x >= wl || y >= hl {
            return None;
        }
        let j = (y + 0.5) as usize * w + (x + 0.5) as usize;
        if sources[j] {
            return Some((j, i));
        }
        let skip = ((free[j] as f64 - 1.5) / step).floor();
        i += if skip >= 1.0 { skip.min(1e6) as u32 } else { 1 };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{backproject, project_zbuffer, DepthRange};
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn the_epipole_of_a_sideways_move_is_at_infinity_along_the_move() {
        let k = Intrinsics::new(100.0, 100.0, 32.0, 24.0, 64, 48).unwrap();
        let t = Isometry3::from_parts(Translation3::new(0.2, 0.0, 0.0), UnitQuaternion::identity());
        let e = epipole(&k, &t);
        assert_eq!(e, [20.0, 0.0, 0.0]);
        assert_eq!(epipolar_direction(e, 5.0, 7.0), Some((1.0, 0.0)));
        // A forward move: the epipole is the principal point, lines run radially.
        let t = Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.5), UnitQuaternion::identity());
        let e = epipole(&k, &t);
        let (dx, dy) = epipolar_direction(e, 42.0, 24.0).unwrap();
        assert_eq!((dx.abs(), dy), (1.0, 0.0));
        assert_eq!(epipolar_direction(e, 32.0, 24.0), None, "at the epipole itself");
    }

    /// A 0.6 m square at 1.5 m in front of a wall at 3 m, seen from the origin and re-projected into a
    /// camera moved `(tx, ty, 0)`: the true depth of a target pixel is the square's or the wall's.
    fn box_on_wall(tx: f64, ty: f64) -> (DepthMap, Vec<bool>, Vec<f32>, InpaintContext) {
        let (w, h) = (96u32, 72u32);
        let k = Intrinsics::new(80.0, 80.0, 48.0, 36.0, w, h).unwrap();
        let truth = |c: f64, r: f64, ox: f64, oy: f64| -> f32 {
            // The ray through pixel (c, r) from a camera at (ox, oy, 0): in the square at z = 1.5?
            let (x, y) = (ox + (c - k.cx) / k.fx * 1.5, oy + (r - k.cy) / k.fy * 1.5);
            if x.abs() <= 0.3 && y.abs() <= 0.3 { 1.5 } else { 3.0 }
        };
        let source: Vec<f32> = (0..w * h).map(|i| truth((i % w) as f64, (i / w) as f64, 0.0, 0.0)).collect();
        let source = DepthMap::new(w, h, source).unwrap();
        // Target camera at (tx, ty, 0) in source coordinates: t_target_from_source moves points by −(tx, ty).
        let t = Isometry3::from_parts(Translation3::new(-tx, -ty, 0.0), UnitQuaternion::identity());
        let proj = project_zbuffer(&backproject(&source, &k, DepthRange { near: 0.1, far: 10.0 }), &t, &k, false);
        let target: Vec<f32> = (0..w * h).map(|i| truth((i % w) as f64, (i / w) as f64, tx, ty)).collect();
        let ctx = InpaintContext { intrinsics: k, seed: 0, t_target_from_source: t };
        (proj.depth, proj.known, target, ctx)
    }

    #[test]
    fn a_disocclusion_behind_a_box_takes_the_wall_depth() {
        for (tx, ty) in [(0.25, 0.0), (-0.2, 0.1), (0.05, -0.3)] {
            let (depth, known, truth, ctx) = box_on_wall(tx, ty);
            let (w, h) = (depth.width() as usize, depth.height() as usize);
            // Pixels on the box's outline (a 4-neighbour of the other depth) are ambiguous at pixel
            // rounding: a lost edge pixel of the box looks like the start of the disocclusion.
            let outline = |j: usize| {
                let (r, c) = (j / w, j % w);
                [(0, 1), (2, 1), (1, 0), (1, 2)].iter().any(|(dr, dc)| {
                    let (rr, cc) = ((r + dr).wrapping_sub(1), (c + dc).wrapping_sub(1));
                    rr < h && cc < w && truth[rr * w + cc] != truth[j]
                })
            };
            let out = Background.inpaint(&depth, &known, &ctx);
            let (mut holes, mut wrong, mut on_outline) = (0, 0, 0);
            for j in 0..truth.len() {
                if known[j] {
                    continue;
                }
                if outline(j) {
                    on_outline += 1;
                    continue;
                }
                holes += 1;
                wrong += ((out.data()[j] - truth[j]).abs() > 1e-4) as usize;
            }
            // The disocclusion is a band 80·t·(1/1.5 − 1/3) ≈ 27·t pixels wide along a 48-pixel edge.
            assert!(holes > 100 && on_outline * 5 < holes, "move ({tx}, {ty}): {holes} holes, {on_outline} on the outline");
            assert_eq!(wrong, 0, "move ({tx}, {ty}): {wrong} of {holes} filled pixels off the true surface");
            // The push–pull fill blends the box into the wall there: the scene tells the two apart.
            let blended = super::super::PushPull.inpaint(&depth, &known, &ctx);
            let off = (0..truth.len()).filter(|j| !known[*j] && (blended.data()[*j] - truth[*j]).abs() > 0.05).count();
            assert!(off * 4 > holes, "push-pull is off on only {off} of {holes}");
        }
    }

    #[test]
    fn a_hole_in_a_ramp_along_the_motion_is_interpolated() {
        // Depth rising 5 mm per column (one surface: the borders differ by 2.6 %), columns 20..30 unknown,
        // sideways motion: a linear fill.
        let (w, h) = (48u32, 4u32);
        let data: Vec<f32> = (0..w * h).map(|i| 2.0 + 0.005 * (i % w) as f32).collect();
        let known: Vec<bool> = (0..w * h).map(|i| !(20..30).contains(&(i % w))).collect();
        let d = DepthMap::new(w, h, data.clone()).unwrap();
        let mut ctx = super::super::test_context(&d);
        ctx.t_target_from_source = Isometry3::translation(0.1, 0.0, 0.0);
        let out = Background.inpaint(&d, &known, &ctx);
        for i in 0..data.len() {
            assert!((out.data()[i] - data[i]).abs() < 1e-5, "pixel {i}: {} vs {}", out.data()[i], data[i]);
        }
    }

    #[test]
    fn only_the_side_a_disocclusion_uncovers_takes_the_farther_border() {
        // A near plane (1.5 m, columns < 20) and a far one (3 m, columns >= 29), columns 20..29 unknown.
        let (w, h) = (48u32, 4u32);
        let (near, far) = (1.5f32, 3.0f32);
        let data: Vec<f32> = (0..w * h).map(|i| if i % w < 20 { near } else { far }).collect();
        let known: Vec<bool> = (0..w * h).map(|i| !(20..29).contains(&(i % w))).collect();
        let d = DepthMap::new(w, h, data).unwrap();
        let mut ctx = super::super::test_context(&d);
        // Points move by +fx·t/z: with t < 0 the near plane moves left farther than the far one and the
        // gap between them is a disocclusion, whose true depth is the far plane.
        ctx.t_target_from_source = Isometry3::translation(-0.1, 0.0, 0.0);
        let out = Background.inpaint(&d, &known, &ctx);
        for i in (0..w * h).filter(|i| !known[*i as usize]) {
            assert_eq!(out.data()[i as usize], far, "disocclusion, column {}", i % w);
        }
        // With t > 0 the near plane moves right over the far one: no motion uncovers this gap, so each
        // pixel copies its nearest known pixel (column 24 is as far from 19 as from 29).
        ctx.t_target_from_source = Isometry3::translation(0.1, 0.0, 0.0);
        let out = Background.inpaint(&d, &known, &ctx);
        let nearest = super::super::Nearest.inpaint(&d, &known, &ctx);
        for i in (0..w * h).filter(|i| !known[*i as usize] && i % w != 24) {
            let want = if i % w < 24 { near } else { far };
            assert_eq!(out.data()[i as usize], want, "column {}", i % w);
            assert_eq!(out.data()[i as usize], nearest.data()[i as usize]);
        }
    }

    #[test]
    fn skipping_by_the_clearance_walks_to_the_same_pixel_as_the_plain_walk() {
        let mut rng = crate::rng::Rng::new(21);
        for share in [0.002, 0.02, 0.2] {
            let (w, h) = (70usize, 50usize);
            let sources: Vec<bool> = (0..w * h).map(|_| rng.uniform() < share).collect();
            let free = clearance(&nearest_source_indices(&sources, w, h), w);
            let none = vec![0.0f32; w * h];
            for _ in 0..400 {
                let (c, r) = (rng.below(w as u64) as f64, rng.below(h as u64) as f64);
                let a = rng.uniform_range(0.0, std::f64::consts::TAU);
                let (dx, dy) = (a.cos(), a.sin());
                let m = dx.abs().max(dy.abs());
                let (dx, dy) = (dx / m, dy / m);
                assert_eq!(first_source(&sources, &free, w, h, c, r, dx, dy), first_source(&sources, &none, w, h, c, r, dx, dy));
            }
        }
    }

    #[test]
    fn without_a_translation_it_is_the_nearest_fill() {
        let (depth, known, _, mut ctx) = box_on_wall(0.25, 0.0);
        ctx.t_target_from_source = Isometry3::identity();
        let a = Background.inpaint(&depth, &known, &ctx);
        let b = super::super::Nearest.inpaint(&depth, &known, &ctx);
        assert_eq!(a.data(), b.data());
    }
}
