//! SE(3) poses on nalgebra: parsing row-major 4×4 matrices, relative poses, transforming points.

use super::Point;
use crate::error::{Error, Result};
use nalgebra::{Isometry3, Matrix3, Matrix4, Rotation3, Translation3, UnitQuaternion};
use rayon::prelude::*;

/// Largest deviation of `RᵀR` from the identity (and of det R from 1) accepted as a rigid rotation;
/// real trajectories store rotations with a few 1e-6 of drift.
pub const RIGIDITY_TOLERANCE: f64 = 1e-3;

/// An isometry from a row-major 4×4 matrix. Rejects non-finite values, a last row other than
/// `0 0 0 1` and a non-rigid rotation part; the rotation is re-orthonormalised.
pub fn pose_from_rows(rows: &[f64; 16]) -> std::result::Result<Isometry3<f64>, String> {
    if rows.iter().any(|v| !v.is_finite()) {
        return Err("pose has non-finite values".into());
    }
    let m = Matrix4::from_row_slice(rows);
    let last = [m[(3, 0)], m[(3, 1)], m[(3, 2)], m[(3, 3)]];
    if last.iter().zip([0.0, 0.0, 0.0, 1.0]).any(|(a, b)| (a - b).abs() > 1e-6) {
        return Err(format!("pose last row is {last:?}, expected [0, 0, 0, 1]"));
    }
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into_owned();
    let orth = (r.transpose() * r - Matrix3::identity()).abs().max();
    let det = r.determinant();
    if orth > RIGIDITY_TOLERANCE || (det - 1.0).abs() > RIGIDITY_TOLERANCE {
        return Err(format!("pose rotation is not rigid (|RᵀR − I|max = {orth:.2e}, det = {det:.6})"));
    }
    // Nearest rotation (polar decomposition R = U·Vᵀ); exact to rounding for an orthonormal input.
    let svd = r.svd(true, true);
    let (u, v_t) = (svd.u.expect("svd u"), svd.v_t.expect("svd v_t"));
    let rot = Rotation3::from_matrix_unchecked(u * v_t);
    let t = Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]);
    Ok(Isometry3::from_parts(t, UnitQuaternion::from_rotation_matrix(&rot)))
}

/// The row-major 4×4 matrix of a pose (the layout shards and pose files store).
pub fn pose_to_rows(pose: &Isometry3<f64>) -> [f64; 16] {
    let m = pose.to_homogeneous();
    let mut out = [0.0; 16];
    for r in 0..4 {
        for c in 0..4 {
            out[r * 4 + c] = m[(r, c)];
        }
    }
    out
}

/// `T_target_from_source` from two camera-to-world poses: `inv(T_world_from_target)·T_world_from_source`.
pub fn relative_pose(t_world_from_target: &Isometry3<f64>, t_world_from_source: &Isometry3<f64>) -> Isometry3<f64> {
    t_world_from_target.inverse() * t_world_from_source
}

/// `t · p` for every point (computed in f64, stored in f32), in input order.
pub fn transform_points(points: &[Point], t: &Isometry3<f64>) -> Vec<Point> {
    let m = t.to_homogeneous();
    let mut out = vec![Point::origin(); points.len()];
    out.par_chunks_mut(8192).zip(points.par_chunks(8192)).for_each(|(o, p)| {
        for (o, p) in o.iter_mut().zip(p) {
            let (x, y, z) = (p.x as f64, p.y as f64, p.z as f64);
            *o = Point::new(
                (m[(0, 0)] * x + m[(0, 1)] * y + m[(0, 2)] * z + m[(0, 3)]) as f32,
                (m[(1, 0)] * x + m[(1, 1)] * y + m[(1, 2)] * z + m[(1, 3)]) as f32,
                (m[(2, 0)] * x + m[(2, 1)] * y + m[(2, 2)] * z + m[(2, 3)]) as f32,
            );
        }
    });
    out
}

/// Checks that `t` is usable; used on poses that come from files.
pub fn check_pose(t: &Isometry3<f64>) -> Result<()> {
    if pose_to_rows(t).iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(Error::InvalidArgument("pose has non-finite values".into()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn rows_round_trip_and_relative_pose() {
        let a = Isometry3::new(Vector3::new(1.0, 2.0, 3.0), Vector3::new(0.1, -0.2, 0.3));
        let b = Isometry3::new(Vector3::new(-1.0, 0.5, 0.0), Vector3::new(-0.3, 0.1, 0.05));
        let back = pose_from_rows(&pose_to_rows(&a)).unwrap();
        let err = (back.to_homogeneous() - a.to_homogeneous()).abs().max();
        assert!(err < 1e-12, "round trip error {err}");
        // A world point seen from b, moved into a's camera, equals the same world point seen from a.
        let pw = nalgebra::Point3::new(0.3, -0.7, 2.5);
        let in_b = b.inverse() * pw;
        let in_a = a.inverse() * pw;
        let t_a_from_b = relative_pose(&a, &b);
        assert!((t_a_from_b * in_b - in_a).norm() < 1e-12);
    }

    #[test]
    fn rejects_non_rigid_and_nan() {
        let mut rows = pose_to_rows(&Isometry3::identity());
        rows[0] = 2.0;
        assert!(pose_from_rows(&rows).unwrap_err().contains("not rigid"));
        rows[0] = f64::NAN;
        assert!(pose_from_rows(&rows).unwrap_err().contains("non-finite"));
        let mut rows = pose_to_rows(&Isometry3::identity());
        rows[15] = 0.0;
        assert!(pose_from_rows(&rows).unwrap_err().contains("last row"));
    }

    #[test]
    fn transform_points_matches_nalgebra() {
        let t = Isometry3::new(Vector3::new(0.1, 0.2, -0.3), Vector3::new(0.4, 0.1, -0.2));
        let pts: Vec<Point> = (0..20000).map(|i| Point::new(i as f32 * 1e-4, 1.0, 2.0 - i as f32 * 1e-5)).collect();
        let out = transform_points(&pts, &t);
        for (p, q) in pts.iter().zip(&out) {
            let e = t * nalgebra::Point3::new(p.x as f64, p.y as f64, p.z as f64);
            assert!((e.x as f32 - q.x).abs() < 1e-6 && (e.y as f32 - q.y).abs() < 1e-6 && (e.z as f32 - q.z).abs() < 1e-6);
        }
    }
}
