//! The overlap ratio of two clouds (radius queries on [`RadiusIndex`]).

use super::{transform_points, Point, RadiusIndex};
use nalgebra::Isometry3;

/// Overlap of two clouds: the fraction of each cloud's points that have a neighbour in the other
/// within the radius, after moving the source into the target frame.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Overlap {
    /// Fraction of source points with a target neighbour (0 when the source is empty).
    pub source: f64,
    /// Fraction of target points with a source neighbour (0 when the target is empty).
    pub target: f64,
}

/// [`Overlap`] of `source` (in its own frame) and `target` under `t_target_from_source`.
pub fn overlap(source: &[Point], target: &[Point], t_target_from_source: &Isometry3<f64>, radius: f32) -> Overlap {
    let moved = transform_points(source, t_target_from_source);
    let (n_source, n_target) = rayon::join(
        || RadiusIndex::new(target, radius).count_with_neighbor(&moved),
        || RadiusIndex::new(&moved, radius).count_with_neighbor(target),
    );
    let ratio = |n: usize, d: usize| if d == 0 { 0.0 } else { n as f64 / d as f64 };
    Overlap { source: ratio(n_source, source.len()), target: ratio(n_target, target.len()) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::radius_index::tests::{brute_count, cloud};
    use crate::rng::Rng;
    use nalgebra::Vector3;

    #[test]
    fn overlap_is_exact_against_brute_force() {
        let mut r = Rng::new(9);
        for (n, m, offset, radius) in [(2000, 1500, 0.0, 0.0375f32), (3000, 3000, 1.0, 0.05), (500, 4000, 0.5, 0.2), (100, 100, 5.0, 0.0375)] {
            let s = cloud(&mut r, n, 0.0);
            let t = cloud(&mut r, m, offset);
            let pose = Isometry3::new(Vector3::new(0.02, -0.01, 0.0), Vector3::new(0.0, 0.0, 0.03));
            let ov = overlap(&s, &t, &pose, radius);
            let moved = transform_points(&s, &pose);
            assert_eq!(ov.source, brute_count(&moved, &t, radius) as f64 / n as f64);
            assert_eq!(ov.target, brute_count(&t, &moved, radius) as f64 / m as f64);
        }
    }

    #[test]
    fn identical_clouds_overlap_fully_and_empty_gives_zero() {
        let mut r = Rng::new(1);
        let s = cloud(&mut r, 1000, 0.0);
        let ov = overlap(&s, &s, &Isometry3::identity(), 0.01);
        assert_eq!((ov.source, ov.target), (1.0, 1.0));
        let ov = overlap(&s, &[], &Isometry3::identity(), 0.01);
        assert_eq!((ov.source, ov.target), (0.0, 0.0));
    }
}
