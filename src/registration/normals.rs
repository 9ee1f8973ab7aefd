//! Surface normals by PCA over a neighbourhood (Open3D's `estimate_normals` with a hybrid search),
//! oriented towards the camera at the origin of the cloud's frame.

use crate::geometry::{Point, RadiusIndex};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// Unit normals of `points`: the eigenvector of the smallest eigenvalue of the covariance of the
/// `max_nn` nearest points within `radius` (the point itself included), flipped to face the camera at
/// the origin (`n·(0 − p) ≥ 0`). A point with fewer than 3 neighbours gets (0, 0, 1) before
/// orientation, as Open3D does.
pub fn estimate_normals(points: &[Point], radius: f32, max_nn: usize) -> Vec<Vector3<f32>> {
    let grid = RadiusIndex::new(points, radius);
    points
        .par_iter()
        .map_init(Vec::new, |nb, p| {
            grid.hybrid(p, max_nn, nb);
            let n = if nb.len() >= 3 { pca_normal(points, nb) } else { Vector3::new(0.0, 0.0, 1.0) };
            if n.dot(&-p.coords.cast::<f64>()) < 0.0 {
                (-n).cast::<f32>()
            } else {
                n.cast::<f32>()
            }
        })
        .collect()
}

/// The smallest-eigenvalue eigenvector of the neighbours' covariance (f64).
fn pca_normal(points: &[Point], nb: &[(u32, f32)]) -> Vector3<f64> {
    let mut mean = Vector3::zeros();
    for &(i, _) in nb {
        mean += points[i as usize].coords.cast::<f64>();
    }
    mean /= nb.len() as f64;
    let mut cov = Matrix3::zeros();
    for &(i, _) in nb {
        let d = points[i as usize].coords.cast::<f64>() - mean;
        cov += d * d.transpose();
    }
    let eig = cov.symmetric_eigen();
    let k = eig.eigenvalues.imin();
    let n: Vector3<f64> = eig.eigenvectors.column(k).into();
    let norm = n.norm();
    if norm > 0.0 && norm.is_finite() {
        n / norm
    } else {
        Vector3::new(0.0, 0.0, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plane_normals_face_the_camera() {
        // The plane z = 2 − 0.5·x seen from the origin: normal ±(0.5, 0, 1)/|·|, facing −z.
        let pts: Vec<Point> = (0..400)
            .map(|i| {
                let (x, y) = ((i % 20) as f32 * 0.01, (i / 20) as f32 * 0.01);
                Point::new(x, y, 2.0 - 0.5 * x)
            })
            .collect();
        let want = -Vector3::new(0.5f32, 0.0, 1.0).normalize();
        for n in estimate_normals(&pts, 0.05, 30) {
            assert!((n - want).norm() < 1e-4, "{n:?}");
        }
    }
}
