//! Ray casting: the z-depth image of the volume's zero level set seen from a camera.
//!
//! Each ray walks the block grid with a 3D DDA over a dense occupancy bitmap, jumping over empty
//! blocks whole; inside allocated blocks it samples the trilinear TSDF, advancing by a fraction
//! of `tsdf · truncation` (at least one voxel), and refines the first + → − crossing.

use super::extract::MAX_CROSSING_TSDF;
use super::integrate::check_inputs;
use super::sample::{BlockDistance, Sampler};
use super::volume::{floor_i32, TsdfVolume};
use crate::error::Result;
use crate::geometry::{DepthMap, Intrinsics};
use nalgebra::{Isometry3, Vector3};
use rayon::prelude::*;

/// In observed space a ray advances by this fraction of `tsdf · truncation` (at least one voxel).
const STEP_FRACTION: f32 = 0.8;
/// Rays are cast in square tiles of this many pixels a side.
const TILE: usize = 8;

/// The state of a DDA walk over the block grid along `o + z·d` (z is the ray parameter).
struct BlockWalk {
    cell: [i32; 3],
    step: [i32; 3],
    /// The z at which the ray leaves the current cell through each axis' next face.
    t_max: [f32; 3],
    /// z between consecutive faces along each axis.
    t_delta: [f32; 3],
}

impl BlockWalk {
    fn new(o: [f32; 3], d: [f32; 3], z: f32, block: f32) -> Self {
        let cell = [0, 1, 2].map(|a| floor_i32((o[a] + z * d[a]) / block));
        let mut w = BlockWalk { cell, step: [0; 3], t_max: [f32::INFINITY; 3], t_delta: [f32::INFINITY; 3] };
        for a in 0..3 {
            if d[a] != 0.0 {
                w.step[a] = if d[a] > 0.0 { 1 } else { -1 };
                let face = (cell[a] + (d[a] > 0.0) as i32) as f32 * block;
                w.t_max[a] = (face - o[a]) / d[a];
                w.t_delta[a] = block / d[a].abs();
            }
        }
        w
    }

    /// The z at which the ray leaves the current cell.
    #[inline]
    fn exit(&self) -> f32 {
        self.t_max[0].min(self.t_max[1]).min(self.t_max[2])
    }

    /// Moves to the next cell along the ray.
    #[inline]
    fn advance(&mut self) {
        let a = if self.t_max[0] <= self.t_max[1] && self.t_max[0] <= self.t_max[2] {
            0
        } else if self.t_max[1] <= self.t_max[2] {
            1
        } else {
            2
        };
        self.cell[a] += self.step[a];
        self.t_max[a] += self.t_delta[a];
    }
}

impl TsdfVolume {
    /// The z-depth (metres) at which each pixel's ray `((c − cx)/fx, (r − cy)/fy, 1)` of a camera
    /// with intrinsics `k` at `t_world_from_camera` first crosses the surface from free space
    /// (trilinear TSDF going from positive to negative, both |tsdf| < [`MAX_CROSSING_TSDF`], between
    /// `min_depth_m` and `max_depth_m`), refined by two secant steps; 0 where no surface is found.
    /// Fails when the intrinsics are invalid or the pose is not finite.
    pub fn raycast(&self, k: &Intrinsics, t_world_from_camera: &Isometry3<f64>) -> Result<DepthMap> {
        check_inputs(None, k, t_world_from_camera)?;
        let mut out = DepthMap::zeros(k.width, k.height);
        if self.coords.is_empty() {
            return Ok(out);
        }
        let distance = BlockDistance::new(self);
        let o = t_world_from_camera.translation.vector.map(|v| v as f32);
        let r = t_world_from_camera.rotation.to_rotation_matrix().into_inner();
        // Tiles of TILE×TILE pixels: neighbouring rays read the same voxels, so they stay in cache.
        let w = k.width as usize;
        out.data_mut().par_chunks_mut(w * TILE).enumerate().for_each(|(band, lines)| {
            let mut sampler = Sampler::new(self);
            let rows = lines.len() / w;
            for c0 in (0..w).step_by(TILE) {
                for i in 0..rows {
                    let yn = ((band * TILE + i) as f64 - k.cy) / k.fy;
                    for c in c0..(c0 + TILE).min(w) {
                        let d = r * Vector3::new((c as f64 - k.cx) / k.fx, yn, 1.0);
                        let d = [d.x as f32, d.y as f32, d.z as f32];
                        lines[i * w + c] = self.march(&mut sampler, &distance, [o.x, o.y, o.z], d).unwrap_or(0.0);
                    }
                }
            }
        });
        Ok(out)
    }

    /// The first + → − crossing along `o + z·d` (world metres; `d` has camera z component 1).
    fn march(&self, s: &mut Sampler, dist: &BlockDistance, o: [f32; 3], d: [f32; 3]) -> Option<f32> {
        let c = &self.config;
        let (trunc, bm) = (c.truncation_m, c.block_size_m());
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let fine = c.voxel_size_m / len;
        // z advance that moves at most one block along every axis.
        let block_z = bm / d[0].abs().max(d[1].abs()).max(d[2].abs());
        let at = |z: f32| [0, 1, 2].map(|a| o[a] + z * d[a]);
        let (mut z, mut z_end) = (c.min_depth_m.max(fine), c.max_depth_m);
        if let Some((lo, hi)) = dist.bounds() {
            // Clip the ray to the box of allocated blocks.
            for a in 0..3 {
                let (lo, hi) = (lo[a] as f32 * bm, hi[a] as f32 * bm);
                if d[a] == 0.0 {
                    if !(lo..=hi).contains(&o[a]) {
                        return None;
                    }
                } else {
                    let (t0, t1) = ((lo - o[a]) / d[a], (hi - o[a]) / d[a]);
                    z = z.max(t0.min(t1));
                    z_end = z_end.min(t0.max(t1));
                }
            }
        }
        let mut walk = BlockWalk::new(o, d, z, bm);
        let mut prev: Option<(f32, f32)> = None;
        let mut last_step = 0.0f32;
        while z <= z_end {
            let k = dist.get(walk.cell);
            if k > 1 {
                // Every block within k − 1 of this one is empty: jump.
                z += (k - 1) as f32 * block_z * 0.999;
                walk = BlockWalk::new(o, d, z, bm);
                prev = None;
                continue;
            }
            if k == 1 {
                z = z.max(walk.exit());
                walk.advance();
                prev = None;
                continue;
            }
            match s.trilinear(at(z)) {
                None => {
                    prev = None;
                    last_step = fine;
                }
                Some(f) => {
                    if let Some((zp, fp)) = prev.filter(|(_, fp)| *fp > 0.0 && f <= 0.0) {
                        if last_step > 1.01 * fine {
                            // Overshot with a long step: walk the last interval again voxel by voxel.
                            z = zp + fine;
                            last_step = fine;
                            continue;
                        }
                        if fp < MAX_CROSSING_TSDF && f > -MAX_CROSSING_TSDF {
                            return Some(refine(s, &at, (zp, fp), (z, f)));
                        }
                    }
                    prev = Some((z, f));
                    last_step = (STEP_FRACTION * f * trunc / len).max(fine);
                }
            }
            z += last_step;
            // Follow the walk to the cell holding z; a skipped empty cell breaks the bracket.
            while walk.exit() <= z {
                walk.advance();
                if walk.exit() <= z && dist.get(walk.cell) > 0 {
                    prev = None;
                }
            }
        }
        None
    }
}

/// Two secant (regula falsi) steps on the bracket `a` (tsdf > 0) – `b` (tsdf ≤ 0).
fn refine(s: &mut Sampler, at: &impl Fn(f32) -> [f32; 3], mut a: (f32, f32), mut b: (f32, f32)) -> f32 {
    let mut z = a.0 + (b.0 - a.0) * a.1 / (a.1 - b.1);
    for _ in 0..2 {
        match s.trilinear(at(z)) {
            Some(f) if f > 0.0 => a = (z, f),
            Some(f) if f < 0.0 => b = (z, f),
            _ => return z,
        }
        z = a.0 + (b.0 - a.0) * a.1 / (a.1 - b.1);
    }
    z
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Point;
    use crate::tsdf::TsdfConfig;

    #[test]
    fn sphere_depth_matches_the_analytic_ray_intersection() {
        let mut v = TsdfVolume::new(TsdfConfig::coarse()).unwrap();
        let (c, r) = (Point::new(0.05, -0.03, 1.5), 0.3f32);
        let m = Point::new(0.45, 0.45, 0.45);
        v.set_from_sdf(&(c - m.coords), &(c + m.coords), 1.0, |p| (p - c).norm() - r);
        let k = Intrinsics::new(200.0, 200.0, 80.0, 60.0, 160, 120).unwrap();
        let depth = v.raycast(&k, &Isometry3::identity()).unwrap();
        let (mut hits, mut worst) = (0, 0.0f32);
        for row in 0..120 {
            for col in 0..160 {
                let dir = Vector3::new((col as f32 - 80.0) / 200.0, (row as f32 - 60.0) / 200.0, 1.0);
                // |z·dir − c|² = r²: the smaller root.
                let (a, b, cc) = (dir.norm_squared(), -2.0 * dir.dot(&c.coords), c.coords.norm_squared() - r * r);
                let disc = b * b - 4.0 * a * cc;
                let got = depth.at(col, row);
                if disc < -0.02 * b * b {
                    assert_eq!(got, 0.0, "pixel ({col}, {row}) misses the sphere");
                }
                // Away from the silhouette, where a voxel of error moves the hit a long way.
                if disc > 0.02 * b * b {
                    assert!(got > 0.0, "pixel ({col}, {row}) sees the sphere");
                    let z = (-b - disc.sqrt()) / (2.0 * a);
                    hits += 1;
                    worst = worst.max((got - z).abs());
                }
            }
        }
        assert!(hits > 2000, "{hits}");
        assert!(worst < 1e-3, "worst |Δz| {worst} m");
    }
}
