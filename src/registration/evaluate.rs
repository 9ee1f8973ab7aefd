//! Scores a benchmark's pairs with one or more descriptors at several sample counts: per pair, sample
//! N points of each (voxel-downsampled) cloud, match their descriptors, measure the inlier ratio under
//! the ground truth, run RANSAC and score it with the official error.
//!
//! Every random draw is seeded from (seed, scene, i, j, N), the same for every descriptor, so two
//! descriptors are compared on the same points and the same RANSAC streams (a paired comparison).

use super::benchmark::{BenchPair, Benchmark};
use super::descriptor::Descriptor;
use super::icp::icp_point_to_point;
use super::kdtree::KdTree;
use super::matching::{match_features, Features};
use super::metrics::{inlier_ratio, registration_error, rre_rte, RR_ERROR};
use super::ransac::{ransac, RansacConfig};
use crate::error::Result;
use crate::geometry::{voxel_downsample, Point};
use crate::rng::{unit_seed, Rng};
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;

/// The protocol's settings.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalConfig {
    /// Clouds are voxel-downsampled to this before description, metres.
    pub voxel: f32,
    /// Points sampled from each cloud (5000 / 2500 / 1000 / 500 / 250 in the papers' tables).
    pub samples: Vec<usize>,
    /// Keep only mutual nearest neighbours.
    pub mutual: bool,
    /// RANSAC settings (its seed is replaced per pair).
    pub ransac: RansacConfig,
    /// Point-to-point ICP iterations refining RANSAC's pose on the whole downsampled clouds (0: none),
    /// pairing points closer than the RANSAC distance.
    pub icp_iterations: usize,
    pub seed: u64,
    /// Describe every point of every cloud instead of only the points some sample count draws (slower,
    /// the same scores: the check that describing only the sampled points changes nothing).
    pub describe_all: bool,
}

impl Default for EvalConfig {
    fn default() -> Self {
        EvalConfig {
            voxel: 0.025,
            samples: vec![5000, 1000, 250],
            mutual: false,
            ransac: RansacConfig::default(),
            icp_iterations: 0,
            seed: 0,
            describe_all: false,
        }
    }
}

/// One pair at one sample count with one descriptor.
#[derive(Clone, Debug, PartialEq)]
pub struct PairScore {
    pub benchmark: String,
    pub scene: String,
    pub i: usize,
    pub j: usize,
    pub samples: usize,
    pub correspondences: usize,
    pub inlier_ratio: f64,
    /// Whether registration recall counts this pair (3DMatch skips consecutive fragments).
    pub counts_for_rr: bool,
    /// The official error `xᵀ·Info·x / Info₀₀` (infinite when RANSAC found nothing).
    pub error: f64,
    pub registered: bool,
    pub rre_deg: f64,
    pub rte_m: f64,
}

/// A cloud, downsampled, with each descriptor's rows for the described points and (for ICP) its k-d tree.
struct Described {
    points: Vec<Point>,
    /// `row_of[k]`: the row of point k in every descriptor's features (`u32::MAX`: not described).
    row_of: Vec<u32>,
    features: Vec<Features>,
    tree: KdTree,
}

impl Described {
    /// Descriptor d's rows of the points `indices` (all described).
    fn rows(&self, d: usize, indices: &[usize]) -> Features {
        let rows: Vec<usize> = indices.iter().map(|&k| self.row_of[k] as usize).collect();
        debug_assert!(rows.iter().all(|&r| r != u32::MAX as usize), "a sampled point was not described");
        self.features[d].select(&rows)
    }
}

/// The points of a pair drawn at sample count `n`: (source indices, target indices, the RANSAC seed).
fn draws(config: &EvalConfig, pair: &BenchPair, n_source: usize, n_target: usize, n: usize) -> (Vec<usize>, Vec<usize>, u64) {
    let key = format!("{}/{}/{}", pair.scene, pair.i, pair.j);
    let rng = Rng::new(unit_seed(config.seed, &key, n as u64));
    let si = sample_indices(n_source, n, &mut rng.fork(0));
    let ti = sample_indices(n_target, n, &mut rng.fork(1));
    (si, ti, rng.fork(2).next_u64())
}

/// A random order of `0..n` (a full Fisher–Yates; [`sample_indices`] keeps the identity order when asked
/// for all `n`).
pub fn permutation(n: usize, rng: &mut Rng) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..n).collect();
    for a in 0..n.saturating_sub(1) {
        let b = a + rng.below((n - a) as u64) as usize;
        idx.swap(a, b);
    }
    idx
}

/// `k` distinct indices below `n` (all of them, in order, when `k ≥ n`), drawn by a partial Fisher–Yates.
pub fn sample_indices(n: usize, k: usize, rng: &mut Rng) -> Vec<usize> {
    if k >= n {
        return (0..n).collect();
    }
    let mut idx: Vec<usize> = (0..n).collect();
    for a in 0..k {
        let b = a + rng.below((n - a) as u64) as usize;
        idx.swap(a, b);
    }
    idx.truncate(k);
    idx
}

/// Scores every pair of `bench` with each of `descriptors`: `out[d]` holds descriptor d's scores, pair
/// by pair, each pair's sample counts in `config.samples` order. `tick` is called after each pair.
pub fn evaluate(
    bench: &Benchmark,
    descriptors: &[Descriptor],
    config: &EvalConfig,
    tick: &mut dyn FnMut(),
) -> Result<Vec<Vec<PairScore>>> {
    // The downsampled clouds, then the points any sample count draws from each (the union over pairs,
    // roles and counts): only those are described.
    let mut points: HashMap<PathBuf, Vec<Point>> = HashMap::new();
    for pair in &bench.pairs {
        for path in [&pair.source_path, &pair.target_path] {
            if !points.contains_key(path) {
                points.insert(path.clone(), voxel_downsample(&crate::ply::read_ply(path)?, config.voxel));
            }
        }
    }
    let mut wanted: HashMap<PathBuf, Vec<bool>> = points.iter().map(|(p, c)| (p.clone(), vec![config.describe_all; c.len()])).collect();
    for pair in &bench.pairs {
        for &n in &config.samples {
            let (si, ti, _) = draws(config, pair, points[&pair.source_path].len(), points[&pair.target_path].len(), n);
            for (path, idx) in [(&pair.source_path, si), (&pair.target_path, ti)] {
                let w = wanted.get_mut(path).expect("loaded");
                idx.into_iter().for_each(|k| w[k] = true);
            }
        }
    }
    let mut cache: HashMap<PathBuf, Arc<Described>> = HashMap::new();
    let mut load = |path: &PathBuf| -> Result<Arc<Described>> {
        if let Some(d) = cache.get(path) {
            return Ok(d.clone());
        }
        let points = points.remove(path).expect("loaded once");
        let keys: Vec<usize> = (0..points.len()).filter(|&k| wanted[path][k]).collect();
        let mut row_of = vec![u32::MAX; points.len()];
        keys.iter().enumerate().for_each(|(r, &k)| row_of[k] = r as u32);
        let features = descriptors.iter().map(|d| d.describe_at(&points, &keys)).collect();
        let tree = KdTree::from_points(if config.icp_iterations > 0 { &points } else { &[] });
        let d = Arc::new(Described { points, row_of, features, tree });
        cache.insert(path.clone(), d.clone());
        Ok(d)
    };
    let mut out = vec![Vec::new(); descriptors.len()];
    for pair in &bench.pairs {
        let target = load(&pair.target_path)?;
        let source = load(&pair.source_path)?;
        for &n in &config.samples {
            for (d, scores) in out.iter_mut().enumerate() {
                scores.push(score_pair(&bench.name, pair, &source, &target, d, n, config));
            }
        }
        tick();
    }
    Ok(out)
}

fn score_pair(
    benchmark: &str,
    pair: &BenchPair,
    source: &Described,
    target: &Described,
    d: usize,
    n: usize,
    config: &EvalConfig,
) -> PairScore {
    let (si, ti, ransac_seed) = draws(config, pair, source.points.len(), target.points.len(), n);
    let sp: Vec<Point> = si.iter().map(|&k| source.points[k]).collect();
    let tp: Vec<Point> = ti.iter().map(|&k| target.points[k]).collect();
    let corr = match_features(&source.rows(d, &si), &target.rows(d, &ti), config.mutual);
    let ir = inlier_ratio(&sp, &tp, &corr, &pair.t_i_from_j);
    let rc = RansacConfig { seed: ransac_seed, ..config.ransac.clone() };
    let (error, rre, rte) = match ransac(&sp, &tp, &corr, &rc) {
        Some(r) => {
            let mut t = r.t_target_from_source;
            if config.icp_iterations > 0 {
                t = icp_point_to_point(
                    &source.points,
                    &target.tree,
                    &target.points,
                    &t,
                    config.ransac.distance,
                    config.icp_iterations,
                );
            }
            let (rre, rte) = rre_rte(&pair.t_i_from_j, &t);
            (registration_error(&pair.t_i_from_j, &t, &pair.info), rre, rte)
        }
        None => (f64::INFINITY, f64::NAN, f64::NAN),
    };
    PairScore {
        benchmark: benchmark.to_string(),
        scene: pair.scene.clone(),
        i: pair.i,
        j: pair.j,
        samples: n,
        correspondences: corr.len(),
        inlier_ratio: ir,
        counts_for_rr: pair.counts_for_rr(benchmark),
        error,
        registered: error <= RR_ERROR,
        rre_deg: rre,
        rte_m: rte,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn permutation_orders_every_index_once_and_at_random() {
        let p = permutation(1000, &mut Rng::new(7));
        let mut sorted = p.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..1000).collect::<Vec<_>>(), "each index once");
        // A random order leaves about one index in place; the identity (what sample_indices(n, n) gives) all.
        assert!(p.iter().enumerate().filter(|(i, v)| i == *v).count() < 10);
        assert_ne!(p, permutation(1000, &mut Rng::new(8)), "another seed, another order");
        assert_eq!(p, permutation(1000, &mut Rng::new(7)), "the seed fixes the order");
        // Each index lands in the first half about half the time over seeds (a biased shuffle would not).
        let first_half = (0..400u64).filter(|&s| permutation(10, &mut Rng::new(s))[..5].contains(&9)).count();
        assert!((160..240).contains(&first_half), "{first_half}");
        assert!(permutation(0, &mut Rng::new(1)).is_empty() && permutation(1, &mut Rng::new(1)) == [0]);
    }
}
