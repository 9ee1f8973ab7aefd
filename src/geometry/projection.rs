//! Z-buffer projection of a point cloud into a camera: the nearest point wins each pixel.

use super::{DepthMap, Intrinsics, Point, F64_TO_INT_MAGIC};
use nalgebra::Isometry3;
use rayon::prelude::*;

/// Marks a pixel that no point hit in [`Projection::source_index`].
pub const NO_SOURCE: u32 = u32::MAX;

/// What [`project_zbuffer`] returns.
#[derive(Clone, Debug, PartialEq)]
pub struct Projection {
    /// Nearest depth per pixel in metres; 0 where no point landed.
    pub depth: DepthMap,
    /// The known-pixel mask: `true` where at least one point landed.
    pub known: Vec<bool>,
    /// Index (into the input points) of the winning point per pixel, or [`NO_SOURCE`]; present when asked.
    pub source_index: Option<Vec<u32>>,
}

/// Points are transformed and projected in blocks of this many, into small arrays the compiler vectorises,
/// then scattered into the z-buffer.
const BLOCK: usize = 64;
/// Fewest points worth a thread of their own.
const MIN_POINTS_PER_THREAD: usize = 32_768;
/// An empty z-buffer cell: above the bits of every positive finite f32.
const EMPTY: u32 = u32::MAX;

/// Projects `points` (in the source frame) through `t_target_from_source` into the camera `k`.
///
/// A point lands at `c = round_half_even(x·fx/z + cx)`, `r = round_half_even(y·fy/z + cy)` when `z > 0`
/// and the pixel is inside the image; each pixel keeps the smallest `z`, ties going to the lowest point
/// index. The result is identical for any thread count: the winner of a pixel is a minimum over a total
/// order `(z, index)`, which does not depend on the order points are visited in. No splatting, no hole
/// filling (reference §3.2).
pub fn project_zbuffer(
    points: &[Point],
    t_target_from_source: &Isometry3<f64>,
    k: &Intrinsics,
    with_source_index: bool,
) -> Projection {
    assert!(points.len() < NO_SOURCE as usize, "too many points for a u32 index");
    let lander = Lander::new(t_target_from_source, k);
    let pixels = lander.pixels;
    // Each thread takes a contiguous run of points and keeps its own per-pixel minimum of z's bits
    // (positive finite f32 compare like their bit patterns); the buffers are merged by minimum, which does
    // not depend on how the points were split. Equal depths are the same depth, so only the source index
    // needs a tie rule: the lowest index among the points at the pixel's minimum, found in a second pass
    // when asked for. Every buffer has one extra cell, `pixels`, where points that miss the image land, so
    // the scatter has no branch.
    let parts = rayon::current_num_threads().clamp(1, points.len().div_ceil(MIN_POINTS_PER_THREAD).max(1));
    let run = points.len().div_ceil(parts).max(1);
    let mut buffers: Vec<Vec<u32>> = points
        .par_chunks(run)
        .map(|pts| {
            let mut buf = vec![EMPTY; pixels + 1];
            lander.scatter_min(pts, &mut buf);
            buf
        })
        .collect();
    if buffers.is_empty() {
        buffers.push(vec![EMPTY; pixels + 1]);
    }
    // Merge into the first buffer, whose cells then become the depth's bits (0.0 where empty).
    let mut merged = buffers.swap_remove(0);
    merged.truncate(pixels);
    let mut known = vec![false; pixels];
    const CHUNK: usize = 16_384;
    merged.par_chunks_mut(CHUNK).zip(known.par_chunks_mut(CHUNK)).enumerate().for_each(|(c, (m, kn))| {
        let start = c * CHUNK;
        for buf in &buffers {
            for (m, b) in m.iter_mut().zip(&buf[start..start + kn.len()]) {
                *m = (*m).min(*b);
            }
        }
        for (m, kn) in m.iter_mut().zip(kn.iter_mut()) {
            *kn = *m != EMPTY;
            *m = if *kn { *m } else { 0.0f32.to_bits() };
        }
    });
    let depth: Vec<f32> = merged.into_iter().map(f32::from_bits).collect();
    let source = with_source_index.then(|| {
        let mut source = vec![NO_SOURCE; pixels];
        let (mut idx, mut zb) = ([0u32; BLOCK], [0u32; BLOCK]);
        for (b, block) in points.chunks(BLOCK).enumerate() {
            lander.land(block, &mut idx, &mut zb);
            for j in 0..block.len() {
                let i = idx[j] as usize;
                if i < pixels && zb[j] == depth[i].to_bits() && source[i] == NO_SOURCE {
                    source[i] = (b * BLOCK + j) as u32;
                }
            }
        }
        source
    });
    Projection { depth: DepthMap::from_checked_parts(k.width, k.height, depth), known, source_index: source }
}

/// Where points land: the transform's rows, the intrinsics and the image size.
struct Lander {
    m: [[f64; 4]; 3],
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    w: f64,
    h: f64,
    /// Number of pixels; also the index of the cell that points outside the image land in.
    pixels: usize,
    avx2: bool,
}

impl Lander {
    fn new(t: &Isometry3<f64>, k: &Intrinsics) -> Lander {
        let h = t.to_homogeneous();
        #[cfg(target_arch = "x86_64")]
        let avx2 = std::is_x86_feature_detected!("avx2");
        #[cfg(not(target_arch = "x86_64"))]
        let avx2 = false;
        Lander {
            m: std::array::from_fn(|r| std::array::from_fn(|c| h[(r, c)])),
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
            w: k.width as f64,
            h: k.height as f64,
            pixels: k.width as usize * k.height as usize,
            avx2,
        }
    }

    /// Lowers `buf[pixel]` to each point's z bits.
    fn scatter_min(&self, points: &[Point], buf: &mut [u32]) {
        let (mut idx, mut zb) = ([0u32; BLOCK], [0u32; BLOCK]);
        for block in points.chunks(BLOCK) {
            self.land(block, &mut idx, &mut zb);
            for j in 0..block.len() {
                let b = &mut buf[idx[j] as usize];
                *b = (*b).min(zb[j]);
            }
        }
    }

    /// Pixel index and z bits of each point of `block` (at most [`BLOCK`]); `pixels` for a point that
    /// does not land (behind the camera, non-finite, or outside the image).
    fn land(&self, block: &[Point], idx: &mut [u32; BLOCK], zb: &mut [u32; BLOCK]) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is set only when the CPU has AVX2.
            return unsafe { self.land_avx2(block, idx, zb) };
        }
        self.land_body(block, idx, zb)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn land_avx2(&self, block: &[Point], idx: &mut [u32; BLOCK], zb: &mut [u32; BLOCK]) {
        self.land_body(block, idx, zb)
    }

    /// The z-buffer's inner loop, compiled twice (baseline and AVX2) around the one formula
    /// [`Lander::project`], which uses separate multiplies and adds and an exact division, so both give
    /// the same bits.
    #[inline(always)]
    fn land_body(&self, block: &[Point], idx: &mut [u32; BLOCK], zb: &mut [u32; BLOCK]) {
        let outside = self.pixels as u32;
        for (j, p) in block.iter().enumerate().take(BLOCK) {
            let (_, _, zc, pixel, inside) = self.project(p);
            idx[j] = if inside { pixel } else { outside };
            zb[j] = (zc as f32).to_bits();
        }
    }

    /// Where one point lands: its camera coordinates `(x, y, z)`, its pixel index `v·W + u` and whether
    /// it lands (z > 0 and finite, pixel inside the image). The pixel index is meaningful only when it lands.
    #[inline(always)]
    fn project(&self, p: &Point) -> (f64, f64, f64, u32, bool) {
        let m = &self.m;
        let (x, y, z) = (p.x as f64, p.y as f64, p.z as f64);
        let zc = m[2][0] * x + m[2][1] * y + m[2][2] * z + m[2][3];
        let xc = m[0][0] * x + m[0][1] * y + m[0][2] * z + m[0][3];
        let yc = m[1][0] * x + m[1][1] * y + m[1][2] * z + m[1][3];
        let zf = zc as f32;
        let u = (xc * self.fx / zc + self.cx).round_ties_even();
        let v = (yc * self.fy / zc + self.cy).round_ties_even();
        let inside = zf > 0.0 && zf < f32::INFINITY && u >= 0.0 && v >= 0.0 && u < self.w && v < self.h;
        // `v·W + u` is an exact integer below 2^32 when inside; adding 1.5·2^52 puts it in the low bits.
        let pixel = ((v * self.w + u) + F64_TO_INT_MAGIC).to_bits() as u32;
        (xc, yc, zc, pixel, inside)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{backproject, DepthRange};

    #[test]
    fn nearest_point_wins_and_ties_go_to_lowest_index() {
        let k = Intrinsics::new(10.0, 10.0, 1.0, 1.0, 3, 3).unwrap();
        let pts = vec![Point::new(0.0, 0.0, 2.0), Point::new(0.0, 0.0, 1.0), Point::new(0.0, 0.0, 1.0)];
        let p = project_zbuffer(&pts, &Isometry3::identity(), &k, true);
        assert_eq!(p.depth.at(1, 1), 1.0);
        assert_eq!(p.source_index.unwrap()[4], 1);
        assert_eq!(p.known.iter().filter(|b| **b).count(), 1);
    }

    #[test]
    fn behind_camera_and_outside_image_are_dropped() {
        let k = Intrinsics::new(10.0, 10.0, 1.0, 1.0, 3, 3).unwrap();
        let pts = vec![Point::new(0.0, 0.0, -1.0), Point::new(10.0, 0.0, 1.0)];
        let p = project_zbuffer(&pts, &Isometry3::identity(), &k, false);
        assert!(p.known.iter().all(|b| !b));
        assert!(p.source_index.is_none());
    }

    #[test]
    fn agrees_with_a_point_by_point_reference_on_any_thread_count() {
        // 100k points in front of, behind and beside a 97x61 camera, many sharing pixels and depths.
        let mut r = crate::rng::Rng::new(9);
        let pts: Vec<Point> = (0..100_000)
            .map(|_| {
                let z = (r.uniform_range(-0.5, 4.0) * 8.0).round() / 8.0;
                Point::new(r.uniform_range(-3.0, 3.0) as f32, r.uniform_range(-2.0, 2.0) as f32, z as f32)
            })
            .collect();
        let k = Intrinsics::new(40.0, 42.0, 48.0, 30.5, 97, 61).unwrap();
        let t = Isometry3::new(nalgebra::Vector3::new(0.1, -0.2, 0.3), nalgebra::Vector3::new(0.05, -0.1, 0.02));
        let m = t.to_homogeneous();
        let (w, h) = (97usize, 61usize);
        let mut best: Vec<Option<(f32, u32)>> = vec![None; w * h];
        for (j, p) in pts.iter().enumerate() {
            let (x, y, z) = (p.x as f64, p.y as f64, p.z as f64);
            let zc = m[(2, 0)] * x + m[(2, 1)] * y + m[(2, 2)] * z + m[(2, 3)];
            let xc = m[(0, 0)] * x + m[(0, 1)] * y + m[(0, 2)] * z + m[(0, 3)];
            let yc = m[(1, 0)] * x + m[(1, 1)] * y + m[(1, 2)] * z + m[(1, 3)];
            if !((zc as f32) > 0.0) {
                continue;
            }
            let u = (xc * k.fx / zc + k.cx).round_ties_even();
            let v = (yc * k.fy / zc + k.cy).round_ties_even();
            if u < 0.0 || v < 0.0 || u >= w as f64 || v >= h as f64 {
                continue;
            }
            let cell = &mut best[v as usize * w + u as usize];
            if cell.is_none_or(|(bz, _)| (zc as f32) < bz) {
                *cell = Some((zc as f32, j as u32));
            }
        }
        let depth: Vec<f32> = best.iter().map(|b| b.map_or(0.0, |b| b.0)).collect();
        let source: Vec<u32> = best.iter().map(|b| b.map_or(NO_SOURCE, |b| b.1)).collect();
        assert!(source.iter().filter(|&&s| s != NO_SOURCE).count() > w * h / 2);
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let p = pool.install(|| project_zbuffer(&pts, &t, &k, true));
            assert_eq!(p.depth.data(), &depth[..], "{threads} threads");
            assert_eq!(p.source_index.as_ref(), Some(&source), "{threads} threads");
            assert!(p.known.iter().zip(&best).all(|(kn, b)| *kn == b.is_some()));
        }
    }

    #[test]
    fn rounding_is_half_to_even() {
        // x·fx/z + cx = 0.5 -> column 0; 1.5 -> column 2.
        let k = Intrinsics::new(1.0, 1.0, 0.0, 0.0, 4, 1).unwrap();
        let pts = vec![Point::new(0.5, 0.0, 1.0), Point::new(1.5, 0.0, 1.0)];
        let p = project_zbuffer(&pts, &Isometry3::identity(), &k, true);
        assert_eq!(p.source_index.unwrap(), vec![0, NO_SOURCE, 1, NO_SOURCE]);
    }

    #[test]
    fn identity_reproduces_a_depth_map_exactly() {
        let k = Intrinsics::new(300.0, 310.0, 63.5, 47.5, 128, 96).unwrap();
        let data: Vec<f32> =
            (0..128 * 96).map(|i| if i % 7 == 0 { 0.0 } else { 0.6 + (i % 97) as f32 * 0.031 }).collect();
        let d = DepthMap::new(128, 96, data).unwrap();
        let pts = backproject(&d, &k, DepthRange::ANY);
        let p = project_zbuffer(&pts, &Isometry3::identity(), &k, false);
        assert_eq!(p.depth, d);
        for (kn, z) in p.known.iter().zip(d.data()) {
            assert_eq!(*kn, *z > 0.0);
        }
    }
}
