//! The scores of a fill against the captured depth (`eval inpaint`), pooled over views. Pixels where the
//! captured depth is valid (inside the working depth range) are scored:
//! - kept: re-projected pixels that survive correction; a kept depth more than [`PENETRATION_M`] behind
//!   the captured surface is a penetration error;
//! - filled: pixels unknown after correction that the fill gave a valid depth: AbsRel, RMSE, δ < 1.25 and
//!   coverage (filled share of the unknown pixels the sensor saw);
//! - the same three over the filled pixels of the edge band: within [`EDGE_BAND_PX`] pixels (Chebyshev)
//!   of a depth edge of the captured map (4-neighbours whose depths differ by more than [`EDGE_JUMP_REL`]
//!   of the nearer);
//! - flying: filled pixels whose depth is more than [`FLYING_M`] from both the nearest (foreground) and
//!   the farthest (background) valid captured depth of their 3×3 neighbourhood;
//! - cloud: the mean distance from the filled pixels' points to the captured cloud (all valid captured
//!   pixels back-projected with the view's intrinsics);
//! - the unknown share: unknown pixels after correction over all pixels of the views.
//!
//! `benchmarks/peers/fill_peers.py` computes the same definitions independently for outside methods.

use crate::geometry::{DepthMap, Intrinsics, Point};
use crate::registration::KdTree;
use serde::Serialize;

/// A kept depth this far behind the captured one is a penetration error (the official τ_gt).
pub const PENETRATION_M: f32 = 0.05;
/// Half-width of the band around captured depth edges, pixels.
pub const EDGE_BAND_PX: usize = 3;
/// Two 4-neighbours form a depth edge when their depths differ by more than this share of the nearer.
pub const EDGE_JUMP_REL: f32 = 0.05;
/// A filled depth farther than this from both the fore- and background of its 3×3 neighbourhood flies.
pub const FLYING_M: f32 = 0.05;

/// AbsRel, squared error and δ < 1.25 sums over a set of pixels.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct ErrorSums {
    pub n: u64,
    abs_rel: f64,
    sq: f64,
    delta_ok: u64,
}

impl ErrorSums {
    fn add(&mut self, z: f32, g: f32) {
        let (z, g) = (z as f64, g as f64);
        self.n += 1;
        self.abs_rel += (z - g).abs() / g;
        self.sq += (z - g) * (z - g);
        self.delta_ok += ((z / g).max(g / z) < 1.25) as u64;
    }
    pub fn abs_rel(&self) -> f64 {
        self.abs_rel / self.n.max(1) as f64
    }
    pub fn rmse(&self) -> f64 {
        (self.sq / self.n.max(1) as f64).sqrt()
    }
    pub fn delta(&self) -> f64 {
        self.delta_ok as f64 / self.n.max(1) as f64
    }
}

/// Sums of one (correction, fill) method over views.
#[derive(Clone, Debug, Default, Serialize)]
pub struct FillScores {
    pub views: u64,
    /// All pixels of the views, and those unknown after correction (valid capture or not).
    pub pixels: u64,
    pub unknown_all: u64,
    pub kept: u64,
    pub kept_wrong: u64,
    kept_abs_rel: f64,
    /// Unknown pixels (after correction) where the sensor has depth.
    pub unknown: u64,
    pub filled: ErrorSums,
    pub band: ErrorSums,
    pub flying: u64,
    cloud_m: f64,
    /// Time spent in the fill, nanoseconds.
    pub fill_ns: u128,
    /// Pixels a `scene` fill took from the scene (of all view pixels).
    pub scene_pixels: u64,
}

impl FillScores {
    /// Adds one view: `known` after correction, `filled` the fill's output, `k` the view's intrinsics.
    pub fn add(&mut self, known: &[bool], filled: &DepthMap, captured: &DepthMap, k: &Intrinsics, range: (f32, f32)) {
        let (w, h) = (captured.width() as usize, captured.height() as usize);
        let valid = |z: f32| z > range.0 && z < range.1;
        let g = captured.data();
        let band = edge_band(captured, range);
        let point = |j: usize, z: f32| {
            let (c, r) = ((j % w) as f64, (j / w) as f64);
            [((c - k.cx) / k.fx * z as f64) as f32, ((r - k.cy) / k.fy * z as f64) as f32, z]
        };
        let mut cloud: Option<KdTree> = None;
        self.views += 1;
        self.pixels += (w * h) as u64;
        self.unknown_all += known.iter().filter(|k| !**k).count() as u64;
        for (j, (kn, z)) in known.iter().zip(filled.data()).enumerate() {
            let (z, g_j) = (*z, g[j]);
            if !valid(g_j) {
                continue;
            }
            if *kn {
                if z > 0.0 {
                    self.kept += 1;
                    self.kept_wrong += (z - g_j > PENETRATION_M) as u64;
                    self.kept_abs_rel += ((z - g_j).abs() / g_j) as f64;
                }
                continue;
            }
            self.unknown += 1;
            if !valid(z) {
                continue;
            }
            self.filled.add(z, g_j);
            if band[j] {
                self.band.add(z, g_j);
            }
            let (fg, bg) = neighbourhood_range(g, w, h, j, &valid);
            self.flying += ((z - fg).abs() > FLYING_M && (z - bg).abs() > FLYING_M) as u64;
            let tree = cloud.get_or_insert_with(|| {
                let pts: Vec<Point> = (0..w * h).filter(|i| valid(g[*i])).map(|i| Point::from(point(i, g[i]))).collect();
                KdTree::from_points(&pts)
            });
            self.cloud_m += tree.nearest(&point(j, z)).map_or(f32::INFINITY, |(_, d2)| d2.sqrt()) as f64;
        }
    }

    pub fn kept_per_view(&self) -> f64 {
        self.kept as f64 / self.views.max(1) as f64
    }
    pub fn wrong_kept_per_view(&self) -> f64 {
        self.kept_wrong as f64 / self.views.max(1) as f64
    }
    pub fn kept_abs_rel(&self) -> f64 {
        self.kept_abs_rel / self.kept.max(1) as f64
    }
    /// Share of all view pixels the scene filled (0 for fills without a scene).
    pub fn scene_share(&self) -> f64 {
        self.scene_pixels as f64 / self.pixels.max(1) as f64
    }

    pub fn unknown_share(&self) -> f64 {
        self.unknown_all as f64 / self.pixels.max(1) as f64
    }
    pub fn coverage(&self) -> f64 {
        self.filled.n as f64 / self.unknown.max(1) as f64
    }
    pub fn flying_share(&self) -> f64 {
        self.flying as f64 / self.filled.n.max(1) as f64
    }
    pub fn cloud_distance_m(&self) -> f64 {
        self.cloud_m / self.filled.n.max(1) as f64
    }
    pub fn ms_per_view(&self) -> f64 {
        self.fill_ns as f64 / 1e6 / self.views.max(1) as f64
    }
}

/// Pixels within [`EDGE_BAND_PX`] (Chebyshev) of a depth edge of `captured`: a valid pixel with a valid
/// 4-neighbour whose depth differs by more than [`EDGE_JUMP_REL`] of the nearer of the two.
pub fn edge_band(captured: &DepthMap, range: (f32, f32)) -> Vec<bool> {
    let (w, h) = (captured.width() as usize, captured.height() as usize);
    let g = captured.data();
    let valid = |z: f32| z > range.0 && z < range.1;
    let jump = |a: f32, b: f32| valid(a) && valid(b) && (a - b).abs() > EDGE_JUMP_REL * a.min(b);
    let mut edge = vec![false; w * h];
    for r in 0..h {
        for c in 0..w {
            let j = r * w + c;
            if c + 1 < w && jump(g[j], g[j + 1]) {
                edge[j] = true;
                edge[j + 1] = true;
            }
            if r + 1 < h && jump(g[j], g[j + w]) {
                edge[j] = true;
                edge[j + w] = true;
            }
        }
    }
    let b = EDGE_BAND_PX;
    let mut band = vec![false; w * h];
    for (j, _) in edge.iter().enumerate().filter(|(_, e)| **e) {
        let (r, c) = (j / w, j % w);
        for rr in r.saturating_sub(b)..(r + b + 1).min(h) {
            band[rr * w + c.saturating_sub(b)..rr * w + (c + b + 1).min(w)].fill(true);
        }
    }
    band
}

/// The least and greatest valid depth of `g` in the 3×3 neighbourhood of pixel `j` (which is valid).
fn neighbourhood_range(g: &[f32], w: usize, h: usize, j: usize, valid: &impl Fn(f32) -> bool) -> (f32, f32) {
    let (r, c) = (j / w, j % w);
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for rr in r.saturating_sub(1)..(r + 2).min(h) {
        for cc in c.saturating_sub(1)..(c + 2).min(w) {
            let z = g[rr * w + cc];
            if valid(z) {
                lo = lo.min(z);
                hi = hi.max(z);
            }
        }
    }
    (lo, hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn k(w: u32, h: u32) -> Intrinsics {
        Intrinsics::new(10.0, 10.0, 0.0, 0.0, w, h).unwrap()
    }

    #[test]
    fn scores_count_penetrations_and_fill_errors_by_hand() {
        // 4 pixels: kept right, kept 10 cm too far (penetration), unknown filled 10% too near, unknown empty.
        let captured = DepthMap::new(4, 1, vec![2.0, 2.0, 2.0, 2.0]).unwrap();
        let filled = DepthMap::new(4, 1, vec![2.0, 2.1, 1.8, 0.0]).unwrap();
        let known = [true, true, false, false];
        let mut s = FillScores::default();
        s.add(&known, &filled, &captured, &k(4, 1), (0.5, 10.0));
        assert_eq!((s.kept, s.kept_wrong, s.unknown, s.filled.n), (2, 1, 2, 1));
        assert!((s.kept_abs_rel() - 0.025).abs() < 1e-6);
        assert!((s.coverage() - 0.5).abs() < 1e-12);
        assert!((s.unknown_share() - 0.5).abs() < 1e-12);
        assert!((s.filled.abs_rel() - 0.1).abs() < 1e-6);
        assert!((s.filled.rmse() - 0.2).abs() < 1e-6);
        assert_eq!(s.filled.delta(), 1.0);
        // 1.8 is 0.2 m from every captured depth (all 2.0): flying; no edge, so no band pixel.
        assert_eq!((s.flying, s.band.n), (1, 0));
        // Pixel 2 at 1.8 m: with cx = 0 its point is (2/10·1.8, 0, 1.8) = (0.36, 0, 1.8); the nearest
        // captured point is pixel 2's own (0.4, 0, 2), at √(0.04² + 0.2²).
        assert!((s.cloud_distance_m() - (0.04f64 * 0.04 + 0.04).sqrt()).abs() < 1e-6);
    }

    #[test]
    fn the_edge_band_is_three_pixels_either_side_of_a_depth_step() {
        // 12 columns: 1 m for columns 0..6, 2 m from 6 on; the edge pixels are columns 5 and 6, the band 2..=9.
        let (w, h) = (12u32, 2u32);
        let g = DepthMap::new(w, h, (0..w * h).map(|i| if i % w < 6 { 1.0 } else { 2.0 }).collect()).unwrap();
        let band = edge_band(&g, (0.1, 10.0));
        for i in 0..(w * h) as usize {
            assert_eq!(band[i], (2..=9).contains(&(i as u32 % w)), "column {}", i as u32 % w);
        }
        // A 4 % step is no edge; an invalid neighbour is no edge.
        let g = DepthMap::new(3, 1, vec![1.0, 1.04, 0.0]).unwrap();
        assert!(edge_band(&g, (0.1, 10.0)).iter().all(|b| !b));
    }

    #[test]
    fn a_blend_across_an_edge_flies_and_a_copy_of_either_side_does_not() {
        // Captured: 1 m | 3 m. Unknown pixels at columns 1 and 2 (both sides of the step).
        let captured = DepthMap::new(4, 1, vec![1.0, 1.0, 3.0, 3.0]).unwrap();
        let known = [true, false, false, true];
        let score = |fill: [f32; 4]| {
            let mut s = FillScores::default();
            s.add(&known, &DepthMap::new(4, 1, fill.to_vec()).unwrap(), &captured, &k(4, 1), (0.1, 10.0));
            s
        };
        let blend = score([1.0, 2.0, 2.0, 3.0]);
        assert_eq!((blend.flying, blend.filled.n, blend.band.n), (2, 2, 2));
        // Copying the background into both: pixel 1 is 2 m from its own depth but 3 m is its neighbour's.
        let background = score([1.0, 3.0, 3.0, 3.0]);
        assert_eq!(background.flying, 0);
        assert!((background.band.abs_rel() - (2.0 / 1.0) / 2.0).abs() < 1e-9);
        // 3 cm off the foreground is within 5 cm: not flying.
        assert_eq!(score([1.0, 1.03, 3.0, 3.0]).flying, 0);
    }
}
