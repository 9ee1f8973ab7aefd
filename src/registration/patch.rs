//! Keypoint patches: the neighbourhood of a keypoint, turned into its local reference frame, as a
//! truncated distance field (TDF) on a `voxels`³ cube centred on the keypoint. A voxel holds
//! `max(0, 1 − d / τ)`, with `d` the distance from its centre to the nearest point and τ the truncation
//! (both in voxels): 1 on the surface, 0 farther than τ from it (3DMatch's volumetric patch, here in a
//! local frame so that the patch does not depend on the pose).

use super::lrf::local_frame;
use crate::error::{Error, Result};
use crate::geometry::{Point, RadiusIndex};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The patch geometry (saved in a descriptor checkpoint: a network only reads the patches it was trained on).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PatchConfig {
    /// Voxels along each edge of the cube (a multiple of 4 for the network).
    pub voxels: usize,
    /// Voxel edge in metres (16 × 1.875 cm: a 30 cm cube, 3DMatch's patch size).
    pub voxel_m: f32,
    /// Truncation of the distance field, in voxels.
    pub truncation_voxels: f32,
    /// Radius of the neighbourhood that fixes the local reference frame, in metres.
    pub lrf_radius_m: f32,
}

impl Default for PatchConfig {
    fn default() -> Self {
        PatchConfig { voxels: 16, voxel_m: 0.01875, truncation_voxels: 2.5, lrf_radius_m: 0.15 }
    }
}

impl PatchConfig {
    /// Checks the geometry; `field` names the config in errors.
    pub fn validate(&self, field: &str) -> Result<()> {
        let bad = |what: &str| Err(Error::InvalidArgument(format!("{field}: {what}")));
        if self.voxels < 4 || self.voxels % 4 != 0 {
            return bad(&format!("voxels must be a positive multiple of 4, got {}", self.voxels));
        }
        if !(self.voxel_m > 0.0 && self.truncation_voxels > 0.0 && self.lrf_radius_m > 0.0) {
            return bad("voxel_m, truncation_voxels and lrf_radius_m must be positive");
        }
        Ok(())
    }

    /// Values per patch.
    pub fn len(&self) -> usize {
        self.voxels * self.voxels * self.voxels
    }

    /// The radius around a keypoint that holds every point that can touch its patch (the cube's half
    /// diagonal plus the truncation).
    pub fn reach_m(&self) -> f32 {
        (self.voxels as f32 * 0.5 * 3f32.sqrt() + self.truncation_voxels) * self.voxel_m
    }
}

/// A cloud with the two radius indexes its patches need (the local frame's neighbourhood and the
/// patch's reach): build once per cloud, then describe any number of keypoints.
pub struct PatchCloud<'a> {
    cloud: &'a [Point],
    cfg: PatchConfig,
    reach: RadiusIndex,
    frame_index: RadiusIndex,
}

impl<'a> PatchCloud<'a> {
    pub fn new(cloud: &'a [Point], cfg: &PatchConfig) -> Self {
        PatchCloud { cloud, cfg: *cfg, reach: RadiusIndex::new(cloud, cfg.reach_m()), frame_index: RadiusIndex::new(cloud, cfg.lrf_radius_m) }
    }

    /// The patches of `keypoints`: `keypoints.len() × cfg.len()` values, patch after patch, each indexed
    /// `(i·n + j)·n + k` along the frame's (x, y, z).
    pub fn patches(&self, keypoints: &[Point]) -> Vec<f32> {
        let cloud = self.cloud;
        let per: Vec<Vec<f32>> = keypoints
            .par_iter()
            .map_init(Vec::new, |ids, centre| {
                self.frame_index.within(centre, ids);
                let near: Vec<Point> = ids.iter().map(|&i| cloud[i]).collect();
                let frame = local_frame(centre, &near, self.cfg.lrf_radius_m);
                self.reach.within(centre, ids);
                let near: Vec<Point> = ids.iter().map(|&i| cloud[i]).collect();
                patch(centre, &frame, &near, &self.cfg)
            })
            .collect();
        per.concat()
    }
}

/// One patch: `points` (those within [`PatchConfig::reach_m`] of `centre`; others are ignored) in the
/// frame `frame` (rows = axes) centred on `centre`.
pub fn patch(centre: &Point, frame: &Matrix3<f32>, points: &[Point], cfg: &PatchConfig) -> Vec<f32> {
    let n = cfg.voxels;
    let t = cfg.truncation_voxels;
    let half = n as f32 / 2.0;
    let mut out = vec![0f32; cfg.len()];
    for p in points {
        // Grid coordinates: voxel v spans [v, v + 1) along each axis, its centre at v + 0.5.
        let q: Vector3<f32> = frame * (p - centre) / cfg.voxel_m + Vector3::repeat(half);
        let lo = q.map(|c| (c - t - 0.5).ceil().max(0.0) as i64);
        let hi = q.map(|c| (c + t - 0.5).floor().min(n as f32 - 1.0) as i64);
        for i in lo.x..=hi.x {
            for j in lo.y..=hi.y {
                for k in lo.z..=hi.z {
                    let d = (Vector3::new(i as f32, j as f32, k as f32) + Vector3::repeat(0.5) - q).norm();
                    if d < t {
                        let v = &mut out[(i as usize * n + j as usize) * n + k as usize];
                        *v = v.max(1.0 - d / t);
                    }
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    #[test]
    fn one_point_gives_the_analytic_field() {
        let cfg = PatchConfig { voxels: 8, voxel_m: 0.1, truncation_voxels: 2.0, lrf_radius_m: 0.1 };
        // A point at grid coordinates (4.2, 3.5, 5.0) in the identity frame.
        let centre = Point::new(1.0, 2.0, 3.0);
        let p = centre + Vector3::new(0.02, -0.05, 0.1);
        let got = patch(&centre, &Matrix3::identity(), &[p], &cfg);
        for i in 0..8 {
            for j in 0..8 {
                for k in 0..8 {
                    let d = ((i as f32 + 0.5 - 4.2).powi(2) + (j as f32 + 0.5 - 3.5).powi(2) + (k as f32 + 0.5 - 5.0).powi(2)).sqrt();
                    let want = (1.0 - d / 2.0).max(0.0);
                    assert!((got[(i * 8 + j) * 8 + k] - want).abs() < 1e-5, "voxel {i} {j} {k}: {} vs {want}", got[(i * 8 + j) * 8 + k]);
                }
            }
        }
    }

    #[test]
    fn patches_do_not_depend_on_the_pose_of_the_cloud() {
        // A corner of two walls and a floor with an asymmetric box: a stable local frame.
        let mut rng = Rng::new(7);
        let mut cloud = Vec::new();
        for _ in 0..6000 {
            let (u, v) = (rng.uniform_range(0.0, 0.4) as f32, rng.uniform_range(0.0, 0.3) as f32);
            cloud.push(Point::new(u, v, 0.0));
            cloud.push(Point::new(u, 0.0, v * 0.8));
            if u < 0.1 && v < 0.07 {
                cloud.push(Point::new(0.05 + u, 0.06 + v, 0.08));
            }
        }
        let keypoints = [Point::new(0.1, 0.08, 0.02), Point::new(0.2, 0.1, 0.0)];
        let cfg = PatchConfig::default();
        let pose = Isometry3::from_parts(Translation3::new(0.4, -1.2, 2.0), UnitQuaternion::from_euler_angles(0.7, -0.4, 2.1)).cast::<f32>();
        let moved: Vec<Point> = cloud.iter().map(|p| pose * p).collect();
        let moved_keys: Vec<Point> = keypoints.iter().map(|p| pose * p).collect();
        let (a, b) = (PatchCloud::new(&cloud, &cfg).patches(&keypoints), PatchCloud::new(&moved, &cfg).patches(&moved_keys));
        assert!(a.iter().filter(|v| **v > 0.5).count() > 200, "the patches see the surfaces");
        let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max);
        assert!(worst < 2e-3, "largest difference {worst}");
    }
}
