//! Z-buffer projection of a point cloud into a camera: the nearest point wins each pixel.

use super::{DepthMap, Intrinsics, Point};
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
    let (w, h) = (k.width as usize, k.height as usize);
    let m = t_target_from_source.to_homogeneous();
    // Each thread takes a contiguous run of points and keeps its own per-pixel minimum of the packed key
    // (z bits above, point index below: positive finite f32 compare like their bit patterns, so a u64
    // minimum is a (z, index) minimum); the buffers are then merged by minimum, which does not depend on
    // how the points were split.
    let threads = rayon::current_num_threads().max(1);
    let chunk = points.len().div_ceil(threads).max(16_384);
    // Pixel and camera depth of point `p`, when it lands in the image.
    let land = |p: &Point| -> Option<(usize, f32)> {
        let (x, y, z) = (p.x as f64, p.y as f64, p.z as f64);
        let zc = m[(2, 0)] * x + m[(2, 1)] * y + m[(2, 2)] * z + m[(2, 3)];
        let zf = zc as f32;
        if !(zf > 0.0 && zf.is_finite()) {
            return None;
        }
        let xc = m[(0, 0)] * x + m[(0, 1)] * y + m[(0, 2)] * z + m[(0, 3)];
        let yc = m[(1, 0)] * x + m[(1, 1)] * y + m[(1, 2)] * z + m[(1, 3)];
        let u = (xc * k.fx / zc + k.cx).round_ties_even();
        let v = (yc * k.fy / zc + k.cy).round_ties_even();
        (u >= 0.0 && v >= 0.0 && u < w as f64 && v < h as f64).then(|| (v as usize * w + u as usize, zf))
    };
    // Each thread takes a contiguous run of points and keeps its own per-pixel minimum of z's bits
    // (positive finite f32 compare like their bit patterns); the buffers are merged by minimum, which
    // does not depend on how the points were split. Equal depths are the same depth, so only the source
    // index needs a tie rule: the lowest index among the points at the pixel's minimum, found in a second
    // pass when asked for.
    let buffers: Vec<Vec<u32>> = points
        .par_chunks(chunk)
        .map(|pts| {
            let mut best = vec![u32::MAX; w * h];
            for p in pts {
                if let Some((i, z)) = land(p) {
                    let b = &mut best[i];
                    *b = (*b).min(z.to_bits());
                }
            }
            best
        })
        .collect();
    let mut depth = vec![0.0f32; w * h];
    let mut known = vec![false; w * h];
    let rows = 64 * w;
    depth.par_chunks_mut(rows).zip(known.par_chunks_mut(rows)).enumerate().for_each(|(c, (d, kn))| {
        let off = c * rows;
        for j in 0..d.len() {
            let b = buffers.iter().map(|buf| buf[off + j]).min().unwrap_or(u32::MAX);
            if b != u32::MAX {
                d[j] = f32::from_bits(b);
                kn[j] = true;
            }
        }
    });
    let source = with_source_index.then(|| {
        let mut source = vec![NO_SOURCE; w * h];
        for (j, p) in points.iter().enumerate() {
            if let Some((i, z)) = land(p) {
                if z == depth[i] && source[i] == NO_SOURCE {
                    source[i] = j as u32;
                }
            }
        }
        source
    });
    Projection {
        depth: DepthMap::from_checked_parts(k.width, k.height, depth),
        known,
        source_index: source,
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
        let data: Vec<f32> = (0..128 * 96).map(|i| if i % 7 == 0 { 0.0 } else { 0.6 + (i % 97) as f32 * 0.031 }).collect();
        let d = DepthMap::new(128, 96, data).unwrap();
        let pts = backproject(&d, &k, DepthRange::ANY);
        let p = project_zbuffer(&pts, &Isometry3::identity(), &k, false);
        assert_eq!(p.depth, d);
        for (kn, z) in p.known.iter().zip(d.data()) {
            assert_eq!(*kn, *z > 0.0);
        }
    }
}
