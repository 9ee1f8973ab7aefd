//! Training pairs for the descriptor: the `ok` rows of pair datasets (their two clouds and the stored
//! `t_target_from_source`) or the pairs of a registration benchmark folder (real frames with their captured
//! poses, e.g. `pointreggpt fragments --single-frames` of the training frames), and corresponding points
//! drawn from them.

use crate::error::{Error, Result};
use crate::geometry::{pose_from_rows, voxel_downsample, Point, RadiusIndex};
use crate::registration::benchmark::find_benchmarks;
use crate::rng::Rng;
use crate::shards::dataset::Dataset;
use crate::shards::Status;
use nalgebra::Isometry3;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Benchmark clouds are voxel-downsampled to this, metres (the build's voxel).
pub const BENCH_VOXEL_M: f32 = 0.025;

/// One pair: two clouds (each in its own camera frame) and the pose that maps the source into the target.
#[derive(Clone)]
pub struct TrainPair {
    pub key: String,
    pub source: Vec<Point>,
    pub target: Vec<Point>,
    /// Per target point of a generated pair: the share of its voxel a sensor saw, re-projected from the
    /// source frame or seen by the scene (`target_known_share + target_scene_share`; the rest a fill made
    /// up); empty for real pairs and for datasets without provenance.
    pub target_observed: Vec<f32>,
    /// A real pair (captured depth and poses) rather than a generated one.
    pub real: bool,
    pub t_target_from_source: Isometry3<f64>,
}

impl TrainPair {
    /// A generated pair from an `ok` row of a pair dataset.
    pub fn from_row(r: crate::shards::PairRow) -> std::result::Result<TrainPair, String> {
        let t = pose_from_rows(&r.t_target_from_source).map_err(|e| format!("pair {}: t_target_from_source: {e}", r.pair_key))?;
        let observed = match r.target_scene_share.len() == r.target_known_share.len() {
            true => r.target_known_share.iter().zip(&r.target_scene_share).map(|(k, s)| k + s).collect(),
            false => r.target_known_share,
        };
        Ok(TrainPair { key: r.pair_key, source: r.source_points, target: r.target_points, target_observed: observed, real: false, t_target_from_source: t })
    }
}

/// The training pairs of `datasets`, in the order given: for a pair dataset (folder or object-store URL)
/// its `ok` rows in unit order; for a benchmark folder (one with `metadata/benchmarks/`) every pair of
/// every benchmark in it.
pub fn load_pairs(datasets: &[PathBuf]) -> Result<Vec<TrainPair>> {
    let mut out = Vec::new();
    for path in datasets {
        if path.join("metadata/benchmarks").is_dir() {
            out.extend(bench_pairs(path)?);
            continue;
        }
        let rows = Dataset::open(path)?.read_pairs()?;
        let before = out.len();
        for r in rows.into_iter().filter(|r| r.status == Status::Ok && !r.source_points.is_empty() && !r.target_points.is_empty()) {
            out.push(TrainPair::from_row(r).map_err(|e| Error::input(path, e))?);
        }
        if out.len() == before {
            return Err(Error::input(path, "no `ok` pair with points: nothing to train a descriptor on"));
        }
    }
    Ok(out)
}

/// `pairs` with at most `ratio` generated pairs per real one: every real pair, and a subset of the
/// generated ones drawn with `seed`, both in their order. Errors when there is no real pair to count by.
pub fn limit_generated(pairs: Vec<TrainPair>, ratio: f64, seed: u64) -> Result<Vec<TrainPair>> {
    if !(ratio.is_finite() && ratio >= 0.0) {
        return Err(Error::config("--generated-ratio", "must be a non-negative number"));
    }
    let real = pairs.iter().filter(|p| p.real).count();
    if real == 0 {
        return Err(Error::config("--generated-ratio", "needs real pairs in --data (benchmark folders) to count by"));
    }
    let generated: Vec<usize> = (0..pairs.len()).filter(|&i| !pairs[i].real).collect();
    let keep = ((ratio * real as f64).floor() as usize).min(generated.len());
    let mut picked: std::collections::HashSet<usize> =
        crate::registration::evaluate::sample_indices(generated.len(), keep, &mut Rng::new(seed).fork(0x6E4)).into_iter().map(|k| generated[k]).collect();
    Ok(pairs.into_iter().enumerate().filter(|(i, p)| p.real || picked.remove(i)).map(|(_, p)| p).collect())
}

/// A target point of a generated pair counts as observed (re-projected or seen by the scene) when at least
/// this share of its voxel's points were, made up by a fill otherwise.
pub const KNOWN_MIN_SHARE: f32 = 0.5;

/// Whether target point `k` of `pair` may be a positive under `known_only`: every point of a real pair,
/// and the observed ones (re-projected or seen by the scene) of a generated pair.
pub fn may_be_positive(pair: &TrainPair, k: usize, known_only: bool) -> bool {
    !known_only || pair.target_observed.get(k).is_none_or(|&s| s >= KNOWN_MIN_SHARE)
}

/// The pairs of the benchmark folder `root`: source = cloud j, target = cloud i, pose = gt.log's
/// `t_i_from_j`, clouds voxel-downsampled to [`BENCH_VOXEL_M`].
fn bench_pairs(root: &Path) -> Result<Vec<TrainPair>> {
    let mut clouds: HashMap<PathBuf, Arc<Vec<Point>>> = HashMap::new();
    let mut cloud = |p: &PathBuf| -> Result<Arc<Vec<Point>>> {
        if let Some(c) = clouds.get(p) {
            return Ok(c.clone());
        }
        let c = Arc::new(voxel_downsample(&crate::ply::read_ply(p)?, BENCH_VOXEL_M));
        clouds.insert(p.clone(), c.clone());
        Ok(c)
    };
    let mut out = Vec::new();
    for bench in find_benchmarks(root)? {
        for p in &bench.pairs {
            let (source, target) = (cloud(&p.source_path)?, cloud(&p.target_path)?);
            let key = format!("{}/{}/{}/{}", bench.name, p.scene, p.i, p.j);
            out.push(TrainPair { key, source: source.to_vec(), target: target.to_vec(), target_observed: Vec::new(), real: true, t_target_from_source: p.t_i_from_j });
        }
    }
    if out.is_empty() {
        return Err(Error::input(root, "a benchmark folder without pairs: nothing to train a descriptor on"));
    }
    Ok(out)
}

/// Up to `n` corresponding points of `pair`: source points drawn without replacement, each with the
/// target point nearest to where the stored pose puts it, kept when that one is within the radius of
/// `target_index` (built on `pair.target`) and, with `known_only`, re-projected rather than filled
/// ([`may_be_positive`]). Returns (source index, target index) pairs.
pub fn correspondences(pair: &TrainPair, target_index: &RadiusIndex, n: usize, known_only: bool, rng: &mut Rng) -> Vec<(usize, usize)> {
    let mut order: Vec<usize> = (0..pair.source.len()).collect();
    let t = pair.t_target_from_source.cast::<f32>();
    let mut out = Vec::with_capacity(n);
    for i in 0..order.len() {
        if out.len() == n {
            break;
        }
        let j = i + rng.below((order.len() - i) as u64) as usize;
        order.swap(i, j);
        if let Some((k, _)) = target_index.nearest(&(t * pair.source[order[i]])) {
            if may_be_positive(pair, k, known_only) {
                out.push((order[i], k));
            }
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
        let pair = TrainPair { key: "k".into(), source, target, target_observed: Vec::new(), real: true, t_target_from_source: t };
        let index = RadiusIndex::new(&pair.target, 0.0375);
        let c = correspondences(&pair, &index, 100, false, &mut rng);
        assert_eq!(c.len(), 100);
        for &(i, k) in &c {
            let (p, q) = (pair.source[i], pair.target[k]);
            assert!(p.x < 0.54, "a source point outside the overlap got a partner: {p}");
            assert!(((t.cast::<f32>() * p) - q).norm() < 0.0375);
        }
    }

    #[test]
    fn known_only_positives_never_land_on_filled_points() {
        let real_point = TrainPair { key: "r".into(), source: vec![], target: vec![Point::origin()], target_observed: vec![], real: true, t_target_from_source: Isometry3::identity() };
        assert!(may_be_positive(&real_point, 0, true), "every point of a real pair");
        let mut rng = Rng::new(5);
        let source: Vec<Point> = (0..3000).map(|_| Point::new(rng.uniform() as f32, rng.uniform() as f32, 2.0)).collect();
        let t = Isometry3::from_parts(Translation3::new(0.05, 0.0, 0.1), UnitQuaternion::identity());
        let target: Vec<Point> = source.iter().map(|p| t.cast::<f32>() * p).collect();
        // The right half of the target was made by a fill.
        let target_observed: Vec<f32> = target.iter().map(|p| if p.x > 0.55 { 0.0 } else { 1.0 }).collect();
        let pair = TrainPair { key: "k".into(), source, target, target_observed, real: false, t_target_from_source: t };
        let index = RadiusIndex::new(&pair.target, 0.0375);
        let known = correspondences(&pair, &index, 500, true, &mut Rng::new(1));
        assert_eq!(known.len(), 500);
        assert_eq!(known.iter().filter(|&&(_, k)| pair.target_observed[k] < 0.5).count(), 0, "a filled point became a positive");
        // The negative control: without the rule, filled points are drawn too.
        let all = correspondences(&pair, &index, 500, false, &mut Rng::new(1));
        assert!(all.iter().filter(|&&(_, k)| pair.target_observed[k] < 0.5).count() > 100);
    }
}
