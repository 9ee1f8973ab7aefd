//! Projective integration of one depth map: allocate the blocks that each pixel's truncation band
//! crosses, then update every touched block independently (rayon) by projecting its voxel centres.
//!
//! Determinism: the allocation walks rows in fixed-size tasks whose key lists are merged in row
//! order, and a voxel's update depends only on its old value and the frame, so the volume is the
//! same bit for bit whatever the thread count.

use super::camera::Camera;
use super::update::{update_block, UpdateParams};
use super::volume::{floor_i32, pack, unpack, TsdfVolume, KEY_BIAS};
use crate::error::{Error, Result};
use crate::geometry::{DepthMap, Intrinsics};
use nalgebra::Isometry3;
use rayon::prelude::*;

/// Image rows per allocation task (fixed, so the allocation order does not depend on threads).
const ROWS_PER_TASK: usize = 8;
/// Slots of the direct-mapped cache that drops repeated block keys before the hash map sees them.
const CACHE_SLOTS: usize = 1024;

/// Checks the arguments of an integration or a ray cast.
pub(crate) fn check_inputs(depth: Option<&DepthMap>, k: &Intrinsics, pose: &Isometry3<f64>) -> Result<()> {
    k.validate()?;
    if let Some(d) = depth {
        if (d.width(), d.height()) != (k.width, k.height) {
            return Err(Error::InvalidArgument(format!(
                "depth map is {}x{} but the intrinsics are for {}x{}",
                d.width(),
                d.height(),
                k.width,
                k.height
            )));
        }
    }
    if !pose.to_homogeneous().iter().all(|v| v.is_finite()) {
        return Err(Error::InvalidArgument("camera pose has non-finite values".into()));
    }
    Ok(())
}

impl TsdfVolume {
    /// Integrates one depth map (metres, 0 = invalid) seen by a camera with intrinsics `k` (pixels)
    /// at `t_world_from_camera`. Pixels whose depth `d` lies outside `(min_depth_m, max_depth_m]`
    /// are ignored. Allocation: every block in the box between the blocks of the two ends of a
    /// pixel's band `[d − truncation, d + truncation]` along its ray (a superset of the blocks the
    /// band crosses). Update: every voxel of every block so touched projects its centre to the
    /// nearest pixel; when that pixel has depth `d` and `sdf = d − z ≥ −truncation` (`z` the
    /// voxel's camera depth), the voxel averages in `min(1, sdf/truncation)` with weight 1 (total
    /// capped at `max_weight`). Fails when the depth map and the intrinsics disagree, or the pose is
    /// not finite or so far from the origin that block coordinates would overflow (±2²⁰ blocks).
    pub fn integrate(&mut self, depth: &DepthMap, k: &Intrinsics, t_world_from_camera: &Isometry3<f64>) -> Result<()> {
        check_inputs(Some(depth), k, t_world_from_camera)?;
        let c = &self.config;
        let (near, far, trunc) = (c.min_depth_m, c.max_depth_m, c.truncation_m);
        let reach = t_world_from_camera.translation.vector.amax() as f32
            + (far + trunc) * ((k.width as f64 / k.fx).hypot(k.height as f64 / k.fy) as f32 + 2.0);
        if reach / c.block_size_m() + 2.0 >= KEY_BIAS as f32 {
            return Err(Error::InvalidArgument(format!(
                "camera at {:?} m is too far from the origin for {} m blocks",
                t_world_from_camera.translation.vector.as_slice(),
                c.block_size_m()
            )));
        }
        let depth: Vec<f32> = depth.data().iter().map(|&d| if d > near && d <= far { d } else { 0.0 }).collect();

        let keys = self.touched_keys(&depth, k, t_world_from_camera);
        self.updates += 1;
        self.frames += 1;
        let stamp = self.updates;
        for key in keys.iter().flatten() {
            let slot = self.allocate(unpack(*key)) as usize;
            self.stamps[slot] = stamp;
        }

        let cam = Camera::new(k, t_world_from_camera);
        let c = &self.config;
        let params = UpdateParams::new(self.side, c.voxel_size_m, c.truncation_m, c.max_weight);
        let blocks =
            self.voxels.par_chunks_mut(params.side.pow(3)).zip(self.coords.par_iter()).zip(self.stamps.par_iter());
        blocks.filter(|(_, st)| **st == stamp).for_each(|((vox, b), _)| update_block(vox, *b, &cam, &depth, &params));
        Ok(())
    }

    /// Keys of the blocks to update (see [`TsdfVolume::integrate`]), per task of [`ROWS_PER_TASK`]
    /// rows, in row order; repeats within a task mostly removed.
    fn touched_keys(&self, depth: &[f32], k: &Intrinsics, t_world_from_camera: &Isometry3<f64>) -> Vec<Vec<u64>> {
        let inv_block = 1.0 / self.config.block_size_m() as f64;
        let trunc = self.config.truncation_m;
        // Camera centre and axes in block units, so that block(p) = floor(o + z·ray).
        let o = t_world_from_camera.translation.vector * inv_block;
        let r = t_world_from_camera.rotation.to_rotation_matrix().into_inner() * inv_block;
        let o = [o.x as f32, o.y as f32, o.z as f32];
        let col = |j: usize| [r[(0, j)] as f32, r[(1, j)] as f32, r[(2, j)] as f32];
        let (rx, ry, rz) = (col(0), col(1), col(2));
        let w = k.width as usize;
        let xn: Vec<f32> = (0..w).map(|c| ((c as f64 - k.cx) / k.fx) as f32).collect();
        depth
            .par_chunks(w * ROWS_PER_TASK)
            .enumerate()
            .map(|(task, rows)| {
                let mut cache = [u64::MAX; CACHE_SLOTS];
                let mut out = Vec::new();
                let mut push = |cell: [i32; 3]| {
                    let key = pack(cell);
                    let slot = (key.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 54) as usize % CACHE_SLOTS;
                    if cache[slot] != key {
                        cache[slot] = key;
                        out.push(key);
                    }
                };
                let (mut ends, mut above) = (vec![0i32; 6 * w], vec![0i32; 6 * w]);
                let mut changed = vec![0u8; w];
                for (i, row) in rows.chunks(w).enumerate() {
                    let yn = (((task * ROWS_PER_TASK + i) as f64 - k.cy) / k.fy) as f32;
                    let base = [0, 1, 2].map(|a| ry[a] * yn + rz[a]);
                    band_cells(row, &xn, base, rx, o, trunc, &mut ends);
                    let up = (i > 0).then(|| (&rows[(i - 1) * w..i * w], &above[..]));
                    new_cells(row, &ends, up, &mut changed);
                    for c in (0..w).filter(|&c| changed[c] != 0) {
                        let e: [i32; 6] = std::array::from_fn(|j| ends[j * w + c]);
                        for z in e[2].min(e[5])..=e[2].max(e[5]) {
                            for y in e[1].min(e[4])..=e[1].max(e[4]) {
                                for x in e[0].min(e[3])..=e[0].max(e[3]) {
                                    push([x, y, z]);
                                }
                            }
                        }
                    }
                    std::mem::swap(&mut ends, &mut above);
                }
                out
            })
            .collect()
    }
}

/// For each pixel `c` of an image row (depth `row[c]`, metres), the block cells of the near and far
/// ends of its truncation band `[max(d − trunc, 0), d + trunc]` along the ray `base + rx·xn[c]`
/// (`o`, `base` and `rx` in block units, so a cell is a floor): `ends[a·w + c]` for the near end
/// along axis `a`, `ends[(a + 3)·w + c]` for the far end. Branch-free, so it vectorises.
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn band_cells(row: &[f32], xn: &[f32], base: [f32; 3], rx: [f32; 3], o: [f32; 3], trunc: f32, ends: &mut [i32]) {
    let w = row.len();
    let (xn, ends) = (&xn[..w], &mut ends[..6 * w]);
    for c in 0..w {
        let (d, x) = (row[c], xn[c]);
        let ray = [0, 1, 2].map(|a| base[a] + rx[a] * x);
        let (z0, z1) = ((d - trunc).max(0.0), d + trunc);
        for a in 0..3 {
            ends[a * w + c] = floor_i32(o[a] + z0 * ray[a]);
            ends[(a + 3) * w + c] = floor_i32(o[a] + z1 * ray[a]);
        }
    }
}

/// `changed[c] = 1` when pixel `c` has depth and neither its left neighbour nor (given `up`: the
/// row above's depths and [`band_cells`]) the pixel above has depth and the same six cells: the
/// pixels whose band boxes are not already listed. Branch-free, so it vectorises.
#[inline(never)]
fn new_cells(row: &[f32], ends: &[i32], up: Option<(&[f32], &[i32])>, changed: &mut [u8]) {
    let w = row.len();
    changed[0] = (row[0] > 0.0) as u8;
    let lanes: [&[i32]; 6] = std::array::from_fn(|j| &ends[j * w..(j + 1) * w]);
    for c in 1..w {
        let mut diff = false;
        for lane in &lanes {
            diff |= lane[c] != lane[c - 1];
        }
        changed[c] = ((row[c] > 0.0) & (diff | (row[c - 1] <= 0.0))) as u8;
    }
    if let Some((up_row, up_ends)) = up {
        let up_lanes: [&[i32]; 6] = std::array::from_fn(|j| &up_ends[j * w..(j + 1) * w]);
        for c in 0..w {
            let mut diff = false;
            for j in 0..6 {
                diff |= lanes[j][c] != up_lanes[j][c];
            }
            changed[c] &= (diff | (up_row[c] <= 0.0)) as u8;
        }
    }
}
