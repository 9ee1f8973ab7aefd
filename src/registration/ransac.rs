//! RANSAC on correspondences (Open3D's `registration_ransac_based_on_correspondence` with the edge-length
//! and distance checkers), seeded so that the same seed gives the same result on any thread count.
//!
//! Iterations run in fixed batches of [`BATCH`]; iteration `i` draws from `Rng::new(seed).fork(i)`, the
//! batch is scored in parallel and reduced in a fixed order (more inliers, then lower RMSE, then the
//! earlier iteration), and the confidence stop is checked between batches only.

use crate::geometry::Point;
use crate::rng::Rng;
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rayon::prelude::*;

/// Iterations scored between two confidence checks.
pub const BATCH: usize = 256;

/// RANSAC settings (Open3D's names in brackets).
#[derive(Clone, Debug, PartialEq)]
pub struct RansacConfig {
    /// Inlier distance, metres [max_correspondence_distance].
    pub distance: f32,
    /// Correspondences per hypothesis [ransac_n].
    pub sample: usize,
    /// Edge-length pre-check: sampled edges in the two clouds agree within this ratio (0 = off)
    /// [CorrespondenceCheckerBasedOnEdgeLength].
    pub edge_ratio: f32,
    /// Iteration budget [max_iteration].
    pub max_iterations: usize,
    /// Stop once this confidence of having drawn an all-inlier sample is reached [confidence].
    pub confidence: f64,
    /// Refit the best hypothesis to all its inliers (least squares).
    pub refine: bool,
    pub seed: u64,
}

impl Default for RansacConfig {
    fn default() -> Self {
        RansacConfig {
            distance: 0.05,
            sample: 3,
            edge_ratio: 0.9,
            max_iterations: 50_000,
            confidence: 0.999,
            refine: true,
            seed: 0,
        }
    }
}

/// The result: `t_target_from_source`, inliers among the correspondences, iterations run.
#[derive(Clone, Debug, PartialEq)]
pub struct RansacResult {
    pub t_target_from_source: Isometry3<f64>,
    pub inliers: usize,
    pub rmse: f64,
    pub iterations: usize,
}

/// The rigid transform minimising Σ|R·s + t − d|² (Kabsch, SVD with the reflection fixed); `None` for
/// fewer than 3 pairs or degenerate ones.
pub fn kabsch(src: &[Vector3<f64>], dst: &[Vector3<f64>]) -> Option<Isometry3<f64>> {
    if src.len() < 3 || src.len() != dst.len() {
        return None;
    }
    let n = src.len() as f64;
    let cs = src.iter().sum::<Vector3<f64>>() / n;
    let cd = dst.iter().sum::<Vector3<f64>>() / n;
    let mut h = Matrix3::zeros();
    for (s, d) in src.iter().zip(dst) {
        h += (s - cs) * (d - cd).transpose();
    }
    let svd = h.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut v = vt.transpose();
    if (v * u.transpose()).determinant() < 0.0 {
        v.column_mut(2).neg_mut();
    }
    let r = v * u.transpose();
    if !r.iter().all(|x| x.is_finite()) {
        return None;
    }
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    Some(Isometry3::from_parts(Translation3::from(cd - rot * cs), rot))
}

/// Estimates `t_target_from_source` from `corr` (source index, target index) into `source`/`target`.
pub fn ransac(source: &[Point], target: &[Point], corr: &[(u32, u32)], config: &RansacConfig) -> Option<RansacResult> {
    let k = config.sample.max(3);
    if corr.len() < k {
        return None;
    }
    let s: Vec<Vector3<f64>> = corr.iter().map(|c| source[c.0 as usize].coords.cast()).collect();
    let t: Vec<Vector3<f64>> = corr.iter().map(|c| target[c.1 as usize].coords.cast()).collect();
    let d2 = (config.distance as f64).powi(2);
    let base = Rng::new(config.seed);
    let mut best: Option<(usize, f64, usize, Isometry3<f64>)> = None;
    let mut needed = config.max_iterations;
    let mut done = 0;
    while done < needed.min(config.max_iterations) {
        let end = (done + BATCH).min(config.max_iterations);
        let batch_best = (done..end)
            .into_par_iter()
            .filter_map(|it| hypothesis(&s, &t, k, config, &mut base.fork(it as u64)).map(|h| (it, h)))
            .map(|(it, h)| {
                let (n, err) = score(&s, &t, &h, d2);
                (n, if n > 0 { (err / n as f64).sqrt() } else { f64::INFINITY }, it, h)
            })
            .reduce_with(better);
        if let Some(b) = batch_best {
            best = Some(match best {
                Some(a) => better(a, b),
                None => b,
            });
        }
        done = end;
        if let Some((n, ..)) = best {
            let fitness = n as f64 / s.len() as f64;
            if fitness >= 1.0 {
                break;
            }
            let est = (1.0 - config.confidence).ln() / (1.0 - fitness.powi(k as i32)).ln();
            if est.is_finite() && est >= 0.0 {
                needed = needed.min(est.ceil() as usize);
            }
        }
    }
    let (mut n, mut rmse, _, mut pose) = best?;
    if config.refine && n >= 3 {
        let (si, ti): (Vec<_>, Vec<_>) = s
            .iter()
            .zip(&t)
            .filter(|(a, b)| (pose * nalgebra::Point3::from(**a) - nalgebra::Point3::from(**b)).norm_squared() < d2)
            .map(|(a, b)| (*a, *b))
            .unzip();
        if let Some(p) = kabsch(&si, &ti) {
            let (n2, e2) = score(&s, &t, &p, d2);
            if n2 >= n {
                (n, rmse, pose) = (n2, if n2 > 0 { (e2 / n2 as f64).sqrt() } else { f64::INFINITY }, p);
            }
        }
    }
    Some(RansacResult { t_target_from_source: pose, inliers: n, rmse, iterations: done })
}

type Candidate = (usize, f64, usize, Isometry3<f64>);

/// More inliers, then lower RMSE, then the earlier iteration: a total order, so reduction order is irrelevant.
fn better(a: Candidate, b: Candidate) -> Candidate {
    let key = |c: &Candidate| (std::cmp::Reverse(c.0), c.1, c.2);
    if key(&b).partial_cmp(&key(&a)) == Some(std::cmp::Ordering::Less) {
        b
    } else {
        a
    }
}

/// One hypothesis: `k` distinct correspondences, the edge-length pre-check, Kabsch, the distance check.
fn hypothesis(
    s: &[Vector3<f64>],
    t: &[Vector3<f64>],
    k: usize,
    config: &RansacConfig,
    rng: &mut Rng,
) -> Option<Isometry3<f64>> {
    let mut pick: Vec<usize> = Vec::with_capacity(k);
    while pick.len() < k {
        let i = rng.below(s.len() as u64) as usize;
        if !pick.contains(&i) {
            pick.push(i);
        }
    }
    let r = config.edge_ratio as f64;
    if r > 0.0 {
        for a in 0..k {
            for b in a + 1..k {
                let (es, et) = ((s[pick[a]] - s[pick[b]]).norm(), (t[pick[a]] - t[pick[b]]).norm());
                if es < r * et || et < r * es {
                    return None;
                }
            }
        }
    }
    let (ps, pt): (Vec<_>, Vec<_>) = pick.iter().map(|&i| (s[i], t[i])).unzip();
    let pose = kabsch(&ps, &pt)?;
    let d2 = (config.distance as f64).powi(2);
    pick.iter()
        .all(|&i| (pose.transform_vector(&s[i]) + pose.translation.vector - t[i]).norm_squared() < d2)
        .then_some(pose)
}

/// Inliers and the sum of their squared residuals.
fn score(s: &[Vector3<f64>], t: &[Vector3<f64>], pose: &Isometry3<f64>, d2: f64) -> (usize, f64) {
    let r = pose.rotation.to_rotation_matrix();
    let tr = pose.translation.vector;
    let mut n = 0;
    let mut err = 0.0;
    for (a, b) in s.iter().zip(t) {
        let e = (r * a + tr - b).norm_squared();
        if e < d2 {
            n += 1;
            err += e;
        }
    }
    (n, err)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_pose_from_30_percent_inliers() {
        let mut rng = Rng::new(5);
        let truth = Isometry3::new(Vector3::new(0.3, -0.2, 0.5), Vector3::new(0.2, -0.4, 0.1));
        let src: Vec<Point> = (0..400)
            .map(|_| Point::new(rng.uniform() as f32 * 2.0, rng.uniform() as f32 * 2.0, rng.uniform() as f32 * 2.0))
            .collect();
        let dst: Vec<Point> = src.iter().map(|p| truth.cast::<f32>() * p).collect();
        let corr: Vec<(u32, u32)> =
            (0..400u32).map(|i| if i % 10 < 3 { (i, i) } else { (i, (i * 7 + 3) % 400) }).collect();
        let r = ransac(&src, &dst, &corr, &RansacConfig::default()).unwrap();
        assert_eq!(r.inliers, 120);
        let d = r.t_target_from_source.inverse() * truth;
        assert!(d.translation.vector.norm() < 1e-5 && d.rotation.angle() < 1e-5);
        assert!(r.iterations < 1000, "confidence stop: {}", r.iterations);
    }
}
