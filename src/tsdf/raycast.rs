//! Ray casting: the z-depth image of the volume's zero level set seen from a camera.

use super::extract::MAX_CROSSING_TSDF;
use super::integrate::check_inputs;
use super::volume::{floor_i32, TsdfVolume, Voxel};
use crate::error::Result;
use crate::geometry::{DepthMap, Intrinsics};
use nalgebra::Isometry3;
use rayon::prelude::*;
pub static CNT: [std::sync::atomic::AtomicU64; 4] = [const { std::sync::atomic::AtomicU64::new(0) }; 4];
fn bump(i: usize) { CNT[i].fetch_add(1, std::sync::atomic::Ordering::Relaxed); }

/// In observed space a ray advances by this fraction of `tsdf · truncation` (at least one voxel).
const STEP_FRACTION: f32 = 0.8;

/// Trilinear TSDF lookup with a one-block cache.
struct Sampler<'a> {
    vol: &'a TsdfVolume,
    side: i32,
    inv_voxel: f32,
    key: [i32; 3],
    block: Option<&'a [Voxel]>,
}

impl<'a> Sampler<'a> {
    fn new(vol: &'a TsdfVolume) -> Self {
        let key = [i32::MIN; 3];
        Sampler { vol, side: vol.side as i32, inv_voxel: 1.0 / vol.config.voxel_size_m, key, block: None }
    }

    #[inline]
    fn block(&mut self, b: [i32; 3]) -> Option<&'a [Voxel]> {
        if b != self.key {
            self.key = b;
            self.block = self.vol.slot(b).map(|s| self.vol.block(s));
        }
        self.block
    }

    #[inline]
    fn voxel(&mut self, g: [i32; 3]) -> Option<Voxel> {
        let s = self.side;
        let block = self.block(g.map(|v| v.div_euclid(s)))?;
        let l = g.map(|v| v.rem_euclid(s) as usize);
        Some(block[l[0] + s as usize * (l[1] + s as usize * l[2])])
    }

    /// The TSDF at `p` (metres) interpolated between the 8 surrounding voxel centres; `None` when
    /// one of them is unallocated or unobserved.
    #[inline]
    fn trilinear(&mut self, p: [f32; 3]) -> Option<f32> {
        let q = p.map(|c| c * self.inv_voxel - 0.5);
        let i0 = q.map(floor_i32);
        let f = [0, 1, 2].map(|a| q[a] - i0[a] as f32);
        let s = self.side;
        let b = i0.map(|v| v.div_euclid(s));
        let l = [0, 1, 2].map(|a| i0[a] - b[a] * s);
        let mut c = [0.0f32; 8];
        if l.iter().all(|&v| v < s - 1) {
            // All 8 corners in one block.
            let block = self.block(b)?;
            let (su, base) = (s as usize, (l[0] + s * (l[1] + s * l[2])) as usize);
            for (n, c) in c.iter_mut().enumerate() {
                let v = block[base + (n & 1) + su * ((n >> 1 & 1) + su * (n >> 2 & 1))];
                if v.weight <= 0.0 {
                    return None;
                }
                *c = v.tsdf;
            }
        } else {
            for (n, c) in c.iter_mut().enumerate() {
                let v = self.voxel([i0[0] + (n & 1) as i32, i0[1] + (n >> 1 & 1) as i32, i0[2] + (n >> 2 & 1) as i32])?;
                if v.weight <= 0.0 {
                    return None;
                }
                *c = v.tsdf;
            }
        }
        let x0 = [c[0] + (c[1] - c[0]) * f[0], c[2] + (c[3] - c[2]) * f[0], c[4] + (c[5] - c[4]) * f[0], c[6] + (c[7] - c[6]) * f[0]];
        let y0 = [x0[0] + (x0[1] - x0[0]) * f[1], x0[2] + (x0[3] - x0[2]) * f[1]];
        Some(y0[0] + (y0[1] - y0[0]) * f[2])
    }
}

impl TsdfVolume {
    /// The z-depth (metres) at which each pixel's ray `((c − cx)/fx, (r − cy)/fy, 1)` of a camera
    /// with intrinsics `k` at `t_world_from_camera` first crosses the surface from free space
    /// (trilinear TSDF going from positive to negative, between `min_depth_m` and `max_depth_m`),
    /// refined by two secant steps; 0 where no surface is found. The ray skips unallocated blocks
    /// whole and advances by `0.8 · tsdf · truncation` (at least a voxel) in observed space.
    /// Fails when the intrinsics are invalid or the pose is not finite.
    pub fn raycast_counts() -> [u64; 4] { let r = [0,1,2,3].map(|i| CNT[i].swap(0, std::sync::atomic::Ordering::Relaxed)); r }
    pub fn raycast(&self, k: &Intrinsics, t_world_from_camera: &Isometry3<f64>) -> Result<DepthMap> {
        check_inputs(None, k, t_world_from_camera)?;
        let (w, h) = (k.width as usize, k.height as usize);
        let o = t_world_from_camera.translation.vector.map(|v| v as f32);
        let r = t_world_from_camera.rotation.to_rotation_matrix().into_inner().map(|v| v as f32);
        let mut out = DepthMap::zeros(k.width, k.height);
        out.data_mut().par_chunks_mut(w).enumerate().for_each(|(row, line)| {
            let mut sampler = Sampler::new(self);
            let yn = ((row as f64 - k.cy) / k.fy) as f32;
            for (c, z_out) in line.iter_mut().enumerate() {
                let xn = ((c as f64 - k.cx) / k.fx) as f32;
                let d = r * nalgebra::Vector3::new(xn, yn, 1.0);
                *z_out = self.march(&mut sampler, [o.x, o.y, o.z], [d.x, d.y, d.z]).unwrap_or(0.0);
            }
        });
        debug_assert_eq!(out.data().len(), w * h);
        Ok(out)
    }

    /// The first + → − crossing along `o + z·d` (world metres; `d` has camera z component 1).
    fn march(&self, s: &mut Sampler, o: [f32; 3], d: [f32; 3]) -> Option<f32> {
        let c = &self.config;
        let (vs, trunc, bm) = (c.voxel_size_m, c.truncation_m, c.block_size_m());
        let inv_bm = 1.0 / bm;
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let fine = vs / len;
        let at = |z: f32| [0, 1, 2].map(|a| o[a] + z * d[a]);
        let mut z = c.min_depth_m.max(fine);
        let mut prev: Option<(f32, f32)> = None;
        let mut last_step = 0.0f32;
        while z <= c.max_depth_m {
            let p = at(z);
            let b = p.map(|v| floor_i32(v * inv_bm));
            if s.block(b).is_none() {
                bump(0);
                // Leave the empty block: the smallest z at which the ray crosses one of its faces.
                let mut exit = f32::INFINITY;
                for a in 0..3 {
                    if d[a] != 0.0 {
                        let face = if d[a] > 0.0 { (b[a] + 1) as f32 * bm } else { b[a] as f32 * bm };
                        exit = exit.min((face - o[a]) / d[a]);
                    }
                }
                z = exit.max(z) + 1e-3 * fine;
                prev = None;
                continue;
            }
            let Some(f) = s.trilinear(p) else {
                bump(1);
                prev = None;
                z += fine;
                continue;
            };
            bump(2);
            if let Some((zp, fp)) = prev {
                if fp > 0.0 && f <= 0.0 {
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
            }
            prev = Some((z, f));
            last_step = (STEP_FRACTION * f * trunc / len).max(fine);
            z += last_step;
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
