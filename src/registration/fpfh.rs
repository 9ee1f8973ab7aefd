//! Fast Point Feature Histograms (Rusu et al. 2009) as Open3D's `compute_fpfh_feature` defines them:
//! 33 bins (11 for each of the angles α, φ, θ), neighbours from a hybrid search (the `max_nn` nearest
//! within the radius), SPFH of each point over its neighbours, then FPFH = SPFH + the neighbours' SPFH
//! weighted by 1/d² and normalised to 100 per angle. Several radii concatenate (multi-scale).

use super::normals::estimate_normals;
use crate::geometry::{Point, RadiusIndex};
use nalgebra::Vector3;
use rayon::prelude::*;
use std::f64::consts::PI;

/// Neighbours at most per FPFH histogram (Open3D's usual `max_nn`).
pub const FPFH_MAX_NN: usize = 100;
/// Normal estimation radius, metres (2 × the 2.5 cm evaluation voxel), and its neighbour cap.
pub const NORMAL_RADIUS: f32 = 0.05;
pub const NORMAL_MAX_NN: usize = 30;

/// Bins per angle, and the histogram length.
pub const BINS: usize = 11;
pub const FPFH_DIM: usize = 3 * BINS;

/// The four pair features of Open3D's `ComputePairFeatures` (α as atan2, φ, θ, distance); zero when
/// the points coincide or the frame is degenerate.
fn pair_features(p1: Vector3<f64>, n1: Vector3<f64>, p2: Vector3<f64>, n2: Vector3<f64>) -> [f64; 4] {
    let mut dp = p2 - p1;
    let d = dp.norm();
    if d == 0.0 {
        return [0.0; 4];
    }
    let (a1, a2) = (n1.dot(&dp) / d, n2.dot(&dp) / d);
    let (mut u, mut w2) = (n1, n2);
    // Open3D swaps when acos|a1| > acos|a2|; acos falls on [0, 1], and a NaN acos (|a| > 1 by rounding)
    // never swaps: the same test without the two acos.
    let phi = if a1.abs() < a2.abs() && a2.abs() <= 1.0 {
        u = n2;
        w2 = n1;
        dp = -dp;
        -a2
    } else {
        a1
    };
    let v = dp.cross(&u);
    let vn = v.norm();
    if vn == 0.0 {
        return [0.0; 4];
    }
    let v = v / vn;
    let w = u.cross(&v);
    [w.dot(&w2).atan2(u.dot(&w2)), v.dot(&w2), phi, d]
}

fn bin(x: f64) -> usize {
    (x.floor().max(0.0) as usize).min(BINS - 1)
}

/// FPFH of every point at one radius, rows of [`FPFH_DIM`] values (f32; computed in f64).
pub fn fpfh(points: &[Point], normals: &[Vector3<f32>], radius: f32, max_nn: usize) -> Vec<f32> {
    assert_eq!(points.len(), normals.len(), "one normal per point");
    let p64: Vec<Vector3<f64>> = points.iter().map(|p| p.coords.cast::<f64>()).collect();
    let n64: Vec<Vector3<f64>> = normals.iter().map(|n| n.cast::<f64>()).collect();
    // Neighbourhoods once: each point's list (sorted by distance, the point itself first).
    let grid = RadiusIndex::new(points, radius);
    let neighbours: Vec<Vec<(u32, f32)>> = points
        .par_iter()
        .map(|p| {
            let mut nb = Vec::new();
            grid.hybrid(p, max_nn, &mut nb);
            nb
        })
        .collect();
    let spfh: Vec<[f64; FPFH_DIM]> = (0..points.len())
        .into_par_iter()
        .map(|i| {
            let nb = &neighbours[i];
            let mut h = [0.0f64; FPFH_DIM];
            if nb.len() > 1 {
                let incr = 100.0 / (nb.len() - 1) as f64;
                for &(j, _) in &nb[1..] {
                    let f = pair_features(p64[i], n64[i], p64[j as usize], n64[j as usize]);
                    h[bin(BINS as f64 * (f[0] + PI) / (2.0 * PI))] += incr;
                    h[BINS + bin(BINS as f64 * (f[1] + 1.0) * 0.5)] += incr;
                    h[2 * BINS + bin(BINS as f64 * (f[2] + 1.0) * 0.5)] += incr;
                }
            }
            h
        })
        .collect();
    let mut out = vec![0.0f32; points.len() * FPFH_DIM];
    out.par_chunks_mut(FPFH_DIM).enumerate().for_each(|(i, row)| {
        let nb = &neighbours[i];
        if nb.len() <= 1 {
            return;
        }
        let mut acc = [0.0f64; FPFH_DIM];
        for &(j, _) in &nb[1..] {
            // Open3D weights by the squared distance it reports (recomputed here in f64).
            let d2 = (p64[j as usize] - p64[i]).norm_squared();
            if d2 == 0.0 {
                continue;
            }
            let inv = 1.0 / d2;
            for (a, s) in acc.iter_mut().zip(&spfh[j as usize]) {
                *a += s * inv;
            }
        }
        // Each angle's weighted part is normalised to 100.
        let mut sum = [0.0f64; 3];
        for (a, s) in sum.iter_mut().enumerate() {
            let total: f64 = acc[a * BINS..(a + 1) * BINS].iter().sum();
            if total != 0.0 {
                *s = 100.0 / total;
            }
        }
        for b in 0..FPFH_DIM {
            row[b] = (acc[b] * sum[b / BINS] + spfh[i][b]) as f32;
        }
    });
    out
}

/// FPFH at each of `radii`, concatenated per point (`33 · radii.len()` values a row).
pub fn fpfh_multi(points: &[Point], normals: &[Vector3<f32>], radii: &[f32], max_nn: usize) -> Vec<f32> {
    let per: Vec<Vec<f32>> = radii.iter().map(|&r| fpfh(points, normals, r, max_nn)).collect();
    let dim = FPFH_DIM * radii.len();
    let mut out = vec![0.0f32; points.len() * dim];
    for (k, f) in per.iter().enumerate() {
        for i in 0..points.len() {
            out[i * dim + k * FPFH_DIM..i * dim + (k + 1) * FPFH_DIM]
                .copy_from_slice(&f[i * FPFH_DIM..(i + 1) * FPFH_DIM]);
        }
    }
    out
}

/// The FPFH rows of a cloud (in its camera frame, metres) at `radii`, with normals by PCA over
/// [`NORMAL_RADIUS`] oriented to the camera: what the `fpfh` descriptor and the FPFH MLP both start from.
pub fn fpfh_features(points: &[Point], radii: &[f32]) -> Vec<f32> {
    let normals = estimate_normals(points, NORMAL_RADIUS, NORMAL_MAX_NN);
    fpfh_multi(points, &normals, radii, FPFH_MAX_NN)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_angle_histogram_sums_to_200_and_only_an_isolated_point_has_none() {
        // SPFH sums to 100 per angle and the weighted neighbour part is normalised to 100, for every
        // point with a neighbour within the radius; a point without one has an all-zero row.
        let mut pts: Vec<Point> = (0..300)
            .map(|i| {
                let a = i as f32 * 0.37;
                Point::new(a.cos() * (1.0 + 0.001 * i as f32), a.sin(), 2.0 + 0.003 * i as f32)
            })
            .collect();
        pts.push(Point::new(10.0, 10.0, 10.0));
        let normals = estimate_normals(&pts, 0.3, 30);
        let f = fpfh(&pts, &normals, 0.3, 50);
        assert_eq!(f.len(), pts.len() * FPFH_DIM);
        let mut with_neighbours = 0;
        for (i, row) in f.chunks(FPFH_DIM).enumerate() {
            // Neighbours by brute force (strictly inside the radius, as the search counts them).
            let alone = pts.iter().enumerate().all(|(j, q)| j == i || (pts[i] - q).norm_squared() >= 0.3 * 0.3);
            if alone {
                assert!(row.iter().all(|v| *v == 0.0), "point {i} has no neighbour but a histogram {row:?}");
                continue;
            }
            with_neighbours += 1;
            for a in 0..3 {
                let s: f32 = row[a * BINS..(a + 1) * BINS].iter().sum();
                assert!((s - 200.0).abs() < 1e-2, "point {i}, angle {a}: sums to {s}, not 200");
            }
        }
        assert_eq!(with_neighbours, 300, "only the far point is isolated");
    }
}
