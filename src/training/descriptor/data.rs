//! Training pairs for the descriptor: the `ok` rows of pair datasets (their two clouds and the stored
//! `t_target_from_source`), and corresponding points drawn from them.

use crate::error::{Error, Result};
use crate::geometry::{pose_from_rows, Point, RadiusIndex};
use crate::rng::Rng;
use crate::shards::dataset::Dataset;
use crate::shards::Status;
use nalgebra::Isometry3;
use std::path::PathBuf;

/// One pair: two clouds (each in its own camera frame) and the pose that maps the source into the target.
pub struct TrainPair {
    pub key: String,
    pub source: Vec<Point>,
    pub target: Vec<Point>,
    pub t_target_from_source: Isometry3<f64>,
}

/// The `ok` pairs of `datasets` (folders or object-store URLs), in dataset then unit order.
pub fn load_pairs(datasets: &[PathBuf]) -> Result<Vec<TrainPair>> {
    let mut out = Vec::new();
    for path in datasets {
        let rows = Dataset::open(path)?.read_pairs()?;
        let before = out.len();
        for r in rows.into_iter().filter(|r| r.status == Status::Ok && !r.source_points.is_empty() && !r.target_points.is_empty()) {
            let t = pose_from_rows(&r.t_target_from_source).map_err(|e| Error::input(path, format!("pair {}: t_target_from_source: {e}", r.pair_key)))?;
            out.push(TrainPair { key: r.pair_key, source: r.source_points, target: r.target_points, t_target_from_source: t });
        }
        if out.len() == before {
            return Err(Error::input(path, "no `ok` pair with points: nothing to train a descriptor on"));
        }
    }
    Ok(out)
}

/// Up to `n` corresponding points of `pair`: source points drawn without replacement, each with the
/// target point nearest to where the stored pose puts it, kept when that one is within the radius of
/// `target_index` (built on `pair.target`). Returns (source point, target point) pairs.
pub fn correspondences(pair: &TrainPair, target_index: &RadiusIndex, n: usize, rng: &mut Rng) -> Vec<(Point, Point)> {
    let mut order: Vec<usize> = (0..pair.source.len()).collect();
    let t = pair.t_target_from_source.cast::<f32>();
    let mut out = Vec::with_capacity(n);
    for i in 0..order.len() {
        if out.len() == n {
            break;
        }
        let j = i + rng.below((order.len() - i) as u64) as usize;
        order.swap(i, j);
        let p = pair.source[order[i]];
        if let Some((k, _)) = target_index.nearest(&(t * p)) {
            out.push((p, pair.target[k]));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn correspondences_land_within_the_radius_under_the_pose() {
        let mut rng = Rng::new(3);
        let source: Vec<Point> = (0..2000).map(|_| Point::new(rng.uniform() as f32, rng.uniform() as f32, 2.0)).collect();
        let t = Isometry3::from_parts(Translation3::new(0.1, -0.2, 0.3), UnitQuaternion::from_euler_angles(0.1, 0.2, -0.3));
        // The target holds the moved source points whose x < 0.5 (half the overlap), jittered by 1 mm.
        let target: Vec<Point> = source.iter().filter(|p| p.x < 0.5).map(|p| t.cast::<f32>() * p + nalgebra::Vector3::new(0.001, 0.0, 0.0)).collect();
        let pair = TrainPair { key: "k".into(), source, target, t_target_from_source: t };
        let index = RadiusIndex::new(&pair.target, 0.0375);
        let c = correspondences(&pair, &index, 100, &mut rng);
        assert_eq!(c.len(), 100);
        for (p, q) in &c {
            assert!(p.x < 0.54, "a source point outside the overlap got a partner: {p}");
            assert!(((t.cast::<f32>() * p) - q).norm() < 0.0375);
        }
    }
}
