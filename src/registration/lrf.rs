//! Local reference frames: a rotation fixed by the shape of a point's neighbourhood, so that a patch
//! expressed in it does not depend on how the cloud is posed.
//!
//! The frame is the eigenbasis of the distance-weighted covariance of the neighbours (weight `r − d`, as
//! SHOT): x along the largest eigenvalue, z along the smallest, each axis's sign chosen so that most of
//! the weighted neighbours lie on its positive side, y = z × x.

use crate::geometry::Point;
use nalgebra::{Matrix3, SymmetricEigen, Vector3};

/// Fewer neighbours than this give the identity frame (a covariance of so few points is not stable).
pub const MIN_NEIGHBOURS: usize = 6;

/// The rotation whose rows are the frame's axes (`local = R · (p − centre)`), from the neighbours of
/// `centre` within `radius`; the identity when fewer than [`MIN_NEIGHBOURS`] or a degenerate spread.
pub fn local_frame(centre: &Point, neighbours: &[Point], radius: f32) -> Matrix3<f32> {
    if neighbours.len() < MIN_NEIGHBOURS {
        return Matrix3::identity();
    }
    let mut cov = Matrix3::<f64>::zeros();
    let mut total = 0.0f64;
    let offsets: Vec<(Vector3<f64>, f64)> = neighbours
        .iter()
        .map(|p| {
            let v = (p - centre).cast::<f64>();
            (v, (radius as f64 - v.norm()).max(0.0))
        })
        .collect();
    for (v, w) in &offsets {
        cov += v * v.transpose() * *w;
        total += w;
    }
    if total <= 0.0 {
        return Matrix3::identity();
    }
    let eig = SymmetricEigen::new(cov / total);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let (l0, l2) = (eig.eigenvalues[order[0]], eig.eigenvalues[order[2]]);
    if !(l0 > 1e-12) || !(l2.is_finite()) {
        return Matrix3::identity();
    }
    // The sign that puts most of the weighted neighbours on the positive side of an axis.
    let orient = |axis: Vector3<f64>| -> Vector3<f64> {
        let side: f64 = offsets.iter().map(|(v, w)| w * v.dot(&axis).signum()).sum();
        if side < 0.0 {
            -axis
        } else {
            axis
        }
    };
    let x = orient(eig.eigenvectors.column(order[0]).into_owned());
    let z = orient(eig.eigenvectors.column(order[2]).into_owned());
    let y = z.cross(&x);
    Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]).cast::<f32>()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use nalgebra::Rotation3;

    /// An asymmetric bump: a patch of a paraboloid with more points on one side.
    fn bump(rng: &mut Rng) -> Vec<Point> {
        (0..400)
            .map(|_| {
                let (u, v) = (rng.uniform_range(-0.05, 0.1) as f32, rng.uniform_range(-0.04, 0.06) as f32);
                Point::new(u, 0.5 * v, 3.0 * (u * u + 0.3 * v * v))
            })
            .collect()
    }

    #[test]
    fn the_frame_turns_with_the_cloud() {
        let mut rng = Rng::new(1);
        let cloud = bump(&mut rng);
        let centre = Point::origin();
        let frame = local_frame(&centre, &cloud, 0.15);
        assert!((frame * frame.transpose() - Matrix3::identity()).norm() < 1e-5, "orthonormal");
        assert!((frame.determinant() - 1.0).abs() < 1e-5, "a rotation");
        for axis in [Vector3::new(0.3, -1.0, 0.2), Vector3::new(1.0, 1.0, 1.0)] {
            let r = Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), 1.1).matrix().cast::<f32>();
            let turned: Vec<Point> = cloud.iter().map(|p| Point::from(r * p.coords)).collect();
            let frame_turned = local_frame(&centre, &turned, 0.15);
            // Each neighbour has the same local coordinates in both: R' · (r p) = R · p.
            assert!((frame_turned * r - frame).norm() < 1e-4, "{frame_turned} {frame}");
        }
    }

    #[test]
    fn too_few_neighbours_give_the_identity() {
        let pts = vec![Point::new(0.01, 0.0, 0.0); MIN_NEIGHBOURS - 1];
        assert_eq!(local_frame(&Point::origin(), &pts, 0.1), Matrix3::identity());
    }
}
