//! Voxel-grid downsampling: one point per occupied voxel, the centroid of the points inside it.

use super::radix::{bits_for, radix_sort_high_bits};
use super::Point;
use rayon::prelude::*;

/// Downsamples `points` to the centroid of each occupied voxel of edge `voxel` metres.
///
/// The grid has its origin at 0: a point belongs to voxel `floor(p / voxel)` (computed in f64). The output
/// is sorted by voxel index `(ix, iy, iz)` lexicographically, and each centroid sums its points in input
/// order, so the result is bit-identical whatever the thread count.
pub fn voxel_downsample(points: &[Point], voxel: f32) -> Vec<Point> {
    assert!(voxel.is_finite() && voxel > 0.0, "voxel size must be positive, got {voxel}");
    if points.is_empty() {
        return Vec::new();
    }
    let inv = 1.0 / voxel as f64;
    let cell = |p: &Point| -> [i64; 3] {
        [(p.x as f64 * inv).floor() as i64, (p.y as f64 * inv).floor() as i64, (p.z as f64 * inv).floor() as i64]
    };
    let empty = || ([i64::MAX; 3], [i64::MIN; 3]);
    let (lo, hi) = points
        .par_chunks(16_384)
        .map(|chunk| {
            let (mut lo, mut hi) = empty();
            for p in chunk {
                let c = cell(p);
                for a in 0..3 {
                    lo[a] = lo[a].min(c[a]);
                    hi[a] = hi[a].max(c[a]);
                }
            }
            (lo, hi)
        })
        .reduce(empty, |(l1, h1), (l2, h2)| {
            (std::array::from_fn(|a| l1[a].min(l2[a])), std::array::from_fn(|a| h1[a].max(h2[a])))
        });
    let bits: [u32; 3] = std::array::from_fn(|a| bits_for((hi[a] - lo[a]) as u64));
    let idx_bits = bits_for(points.len() as u64 - 1).max(1);
    let total = bits[0] + bits[1] + bits[2] + idx_bits;
    if total > 64 {
        return downsample_by_sort(points, &cell);
    }
    // Key = voxel index packed as (ix, iy, iz) lexicographically, then the point index: sorting the keys
    // orders voxels and keeps input order inside each voxel.
    let mut keys: Vec<u64> = points
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let c = cell(p);
            let v = ((c[0] - lo[0]) as u64) << (bits[1] + bits[2]) | ((c[1] - lo[1]) as u64) << bits[2] | (c[2] - lo[2]) as u64;
            (v << idx_bits) | i as u64
        })
        .collect();
    radix_sort_high_bits(&mut keys, idx_bits, total);
    let mask = (1u64 << idx_bits) - 1;
    let mut out = Vec::new();
    let (mut current, mut n, mut sum) = (u64::MAX, 0u32, [0.0f64; 3]);
    for k in keys {
        let v = k >> idx_bits;
        if v != current {
            if n > 0 {
                out.push(centroid(sum, n));
            }
            (current, n, sum) = (v, 0, [0.0; 3]);
        }
        let p = &points[(k & mask) as usize];
        sum[0] += p.x as f64;
        sum[1] += p.y as f64;
        sum[2] += p.z as f64;
        n += 1;
    }
    out.push(centroid(sum, n));
    out
}

fn centroid(sum: [f64; 3], n: u32) -> Point {
    let n = n as f64;
    Point::new((sum[0] / n) as f32, (sum[1] / n) as f32, (sum[2] / n) as f32)
}

/// The same result for extents too wide to pack in 64 bits: sort point indices by (voxel, index).
fn downsample_by_sort(points: &[Point], cell: &(dyn Fn(&Point) -> [i64; 3] + Sync)) -> Vec<Point> {
    let cells: Vec<[i64; 3]> = points.par_iter().map(cell).collect();
    let mut order: Vec<u32> = (0..points.len() as u32).collect();
    order.par_sort_by_key(|&i| (cells[i as usize], i));
    let mut out = Vec::new();
    let mut start = 0;
    while start < order.len() {
        let c = cells[order[start] as usize];
        let (mut n, mut sum) = (0u32, [0.0f64; 3]);
        while start < order.len() && cells[order[start] as usize] == c {
            let p = &points[order[start] as usize];
            sum[0] += p.x as f64;
            sum[1] += p.y as f64;
            sum[2] += p.z as f64;
            n += 1;
            start += 1;
        }
        out.push(centroid(sum, n));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use std::collections::BTreeMap;

    /// Independent reference: a BTreeMap keyed by voxel index, points summed in input order.
    fn brute_force(points: &[Point], voxel: f32) -> Vec<Point> {
        let mut m: BTreeMap<(i64, i64, i64), (f64, f64, f64, f64)> = BTreeMap::new();
        for p in points {
            let k = (
                (p.x as f64 / voxel as f64).floor() as i64,
                (p.y as f64 / voxel as f64).floor() as i64,
                (p.z as f64 / voxel as f64).floor() as i64,
            );
            let e = m.entry(k).or_default();
            e.0 += p.x as f64;
            e.1 += p.y as f64;
            e.2 += p.z as f64;
            e.3 += 1.0;
        }
        m.values().map(|s| Point::new((s.0 / s.3) as f32, (s.1 / s.3) as f32, (s.2 / s.3) as f32)).collect()
    }

    #[test]
    fn agrees_with_brute_force_on_random_clouds() {
        let mut r = Rng::new(11);
        for &(n, voxel) in &[(1usize, 0.025f32), (1000, 0.025), (50_000, 0.025), (20_000, 0.002), (5000, 1.0)] {
            let pts: Vec<Point> = (0..n)
                .map(|_| Point::new(r.uniform_range(-1.5, 1.5) as f32, r.uniform_range(-1.5, 1.5) as f32, r.uniform_range(0.5, 3.5) as f32))
                .collect();
            assert_eq!(voxel_downsample(&pts, voxel), brute_force(&pts, voxel), "n={n} voxel={voxel}");
        }
    }

    #[test]
    fn wide_extent_uses_the_fallback_path_and_still_agrees() {
        // 1 mm voxels over ±1 km need more than 64 key bits.
        let mut r = Rng::new(5);
        let pts: Vec<Point> = (0..3000)
            .map(|_| Point::new(r.uniform_range(-1000.0, 1000.0) as f32, r.uniform_range(-1000.0, 1000.0) as f32, r.uniform_range(-1000.0, 1000.0) as f32))
            .collect();
        assert_eq!(voxel_downsample(&pts, 0.001), brute_force(&pts, 0.001));
    }

    #[test]
    fn negative_coordinates_floor_towards_minus_infinity() {
        let pts = vec![Point::new(-0.01, 0.0, 0.0), Point::new(0.01, 0.0, 0.0)];
        assert_eq!(voxel_downsample(&pts, 0.025).len(), 2);
    }
}
