//! Projective integration of one depth map: allocate the blocks that each pixel's truncation band
//! crosses, then update every touched block independently (rayon) by projecting its voxel centres.
//!
//! Determinism: the allocation walks rows in fixed-size tasks whose key lists are merged in row
//! order, and a voxel's update depends only on its old value and the frame, so the volume is the
//! same bit for bit whatever the thread count.

use super::volume::{floor_i32, pack, unpack, TsdfVolume, Voxel, KEY_BIAS};
use crate::error::{Error, Result};
use crate::geometry::{DepthMap, Intrinsics};
use nalgebra::{Isometry3, Matrix3, Vector3};
use rayon::prelude::*;

/// Image rows per allocation task (fixed, so the allocation order does not depend on threads).
const ROWS_PER_TASK: usize = 8;
/// Slots of the direct-mapped cache that drops repeated block keys before the hash map sees them.
const CACHE_SLOTS: usize = 1024;

/// A pinhole camera in f32 for the inner loops: world → camera rotation and translation.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Camera {
    /// `R_camera_from_world`, row-major.
    pub(crate) r: [[f32; 3]; 3],
    /// `t_camera_from_world`, metres.
    pub(crate) t: [f32; 3],
    pub(crate) fx: f32,
    pub(crate) fy: f32,
    pub(crate) cx: f32,
    pub(crate) cy: f32,
    pub(crate) width: usize,
    pub(crate) height: usize,
}

impl Camera {
    pub(crate) fn new(k: &Intrinsics, t_world_from_camera: &Isometry3<f64>) -> Camera {
        let inv = t_world_from_camera.inverse();
        let m: Matrix3<f64> = inv.rotation.to_rotation_matrix().into_inner();
        let t: Vector3<f64> = inv.translation.vector;
        Camera {
            r: [0, 1, 2].map(|i| [0, 1, 2].map(|j| m[(i, j)] as f32)),
            t: [t.x as f32, t.y as f32, t.z as f32],
            fx: k.fx as f32,
            fy: k.fy as f32,
            cx: k.cx as f32,
            cy: k.cy as f32,
            width: k.width as usize,
            height: k.height as usize,
        }
    }

    /// `R·p + t`: a world point in camera coordinates.
    #[inline]
    pub(crate) fn to_camera(&self, p: [f32; 3]) -> [f32; 3] {
        let r = &self.r;
        [0, 1, 2].map(|i| r[i][0] * p[0] + r[i][1] * p[1] + r[i][2] * p[2] + self.t[i])
    }
}

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

/// Calls `visit` for every cell of the unit grid that the segment `a → b` crosses, in order
/// (Amanatides–Woo), ending exactly at `b`'s cell.
#[inline]
fn traverse(a: [f32; 3], b: [f32; 3], mut visit: impl FnMut([i32; 3])) {
    let mut cell = a.map(floor_i32);
    let end = b.map(floor_i32);
    let mut step = [0i32; 3];
    let mut t_max = [f32::INFINITY; 3];
    let mut t_delta = [f32::INFINITY; 3];
    for i in 0..3 {
        let d = b[i] - a[i];
        step[i] = (end[i] - cell[i]).signum();
        if step[i] != 0 {
            let boundary = if step[i] > 0 { (cell[i] + 1) as f32 } else { cell[i] as f32 };
            t_max[i] = (boundary - a[i]) / d;
            t_delta[i] = 1.0 / d.abs();
        }
    }
    visit(cell);
    let steps = (0..3).map(|i| (end[i] - cell[i]).abs()).sum::<i32>();
    for _ in 0..steps {
        // The axis whose boundary comes first, among those not yet at the end cell.
        let mut axis = 3;
        for i in 0..3 {
            if cell[i] != end[i] && (axis == 3 || t_max[i] < t_max[axis]) {
                axis = i;
            }
        }
        cell[axis] += step[axis];
        t_max[axis] += t_delta[axis];
        visit(cell);
    }
}

impl TsdfVolume {
    /// Integrates one depth map (metres, 0 = invalid) seen by a camera with intrinsics `k` (pixels)
    /// at `t_world_from_camera`: each voxel of the blocks crossed by a pixel's band
    /// `[d − truncation, d + truncation]` projects its centre to the nearest pixel; with that
    /// pixel's depth `d` inside `(min_depth_m, max_depth_m]` and `sdf = d − z ≥ −truncation`, it
    /// averages in `min(1, sdf/truncation)` with weight 1 (total capped at `max_weight`).
    /// Fails when the depth map and the intrinsics disagree, or the pose is not finite or so far
    /// from the origin that block coordinates would overflow (±2²⁰ blocks).
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

        let t0 = std::time::Instant::now();
        let keys = self.touched_keys(&depth, k, t_world_from_camera);
        let t1 = t0.elapsed();
        self.updates += 1;
        self.frames += 1;
        let stamp = self.updates;
        for key in keys.iter().flatten() {
            let slot = self.allocate(unpack(*key)) as usize;
            self.stamps[slot] = stamp;
        }

        let t2 = t0.elapsed();
        let cam = Camera::new(k, t_world_from_camera);
        let (side, cfg) = (self.side, self.config.clone());
        let blocks = self.voxels.par_chunks_mut(side * side * side).zip(self.coords.par_iter()).zip(self.stamps.par_iter());
        blocks.filter(|(_, st)| **st == stamp).for_each(|((vox, b), _)| {
            update_block(vox, *b, side, &cam, &depth, cfg.voxel_size_m, trunc, cfg.max_weight);
        });
        if std::env::var_os("TSDF_DEBUG").is_some() {
            let touched = self.stamps.iter().filter(|s| **s == stamp).count();
            eprintln!("keys {} touched {} of {} | alloc {:?} merge {:?} update {:?}", keys.iter().map(|k| k.len()).sum::<usize>(), touched, self.coords.len(), t1, t2 - t1, t0.elapsed() - t2);
        }
        Ok(())
    }

    /// Keys of the blocks crossed by each valid pixel's truncation band, per task of
    /// [`ROWS_PER_TASK`] rows, in row order (repeats within a task mostly removed).
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
                let mut last = [[i32::MIN; 3]; 2];
                for (i, row) in rows.chunks(w).enumerate() {
                    let yn = (((task * ROWS_PER_TASK + i) as f64 - k.cy) / k.fy) as f32;
                    let base = [0, 1, 2].map(|a| ry[a] * yn + rz[a]);
                    for (&d, &x) in row.iter().zip(&xn) {
                        if d <= 0.0 {
                            continue;
                        }
                        let ray = [0, 1, 2].map(|a| base[a] + rx[a] * x);
                        let (z0, z1) = ((d - trunc).max(0.0), d + trunc);
                        let a = [0, 1, 2].map(|i| floor_i32(o[i] + z0 * ray[i]));
                        let b = [0, 1, 2].map(|i| floor_i32(o[i] + z1 * ray[i]));
                        if [a, b] == last {
                            continue;
                        }
                        last = [a, b];
                        let (lo, hi) = (std::array::from_fn::<i32, 3, _>(|i| a[i].min(b[i])), std::array::from_fn::<i32, 3, _>(|i| a[i].max(b[i])));
                        for z in lo[2]..=hi[2] {
                            for y in lo[1]..=hi[1] {
                                for x in lo[0]..=hi[0] {
                                    push([x, y, z]);
                                }
                            }
                        }
                    }
                }
                out
            })
            .collect()
    }
}

/// The projective update of one block at block coordinate `b` (see [`TsdfVolume::integrate`]);
/// `depth` is row-major metres with out-of-range values already 0.
#[allow(clippy::too_many_arguments)]
#[inline]
fn update_block(vox: &mut [Voxel], b: [i32; 3], side: usize, cam: &Camera, depth: &[f32], voxel: f32, trunc: f32, max_w: f32) {
    let n = side as i32;
    let origin = [0, 1, 2].map(|a| ((b[a] * n) as f32 + 0.5) * voxel);
    let base = cam.to_camera(origin);
    // Camera-frame steps of one voxel along world x, y, z: columns of R scaled.
    let step = |j: usize| [cam.r[0][j] * voxel, cam.r[1][j] * voxel, cam.r[2][j] * voxel];
    let (dx, dy, dz) = (step(0), step(1), step(2));
    let (w, h) = (cam.width as f32, cam.height as f32);
    let inv_trunc = 1.0 / trunc;
    for (zi, plane) in vox.chunks_exact_mut(side * side).enumerate() {
        for (yi, row) in plane.chunks_exact_mut(side).enumerate() {
            let (fz, fy) = (zi as f32, yi as f32);
            let mut p = [0, 1, 2].map(|a| base[a] + dz[a] * fz + dy[a] * fy);
            for v in row.iter_mut() {
                let z = p[2];
                if z > 0.0 {
                    let inv_z = 1.0 / z;
                    let u = cam.fx * p[0] * inv_z + cam.cx + 0.5;
                    let r = cam.fy * p[1] * inv_z + cam.cy + 0.5;
                    if u >= 0.0 && u < w && r >= 0.0 && r < h {
                        let d = depth[r as usize * cam.width + u as usize];
                        let sdf = d - z;
                        if d > 0.0 && sdf >= -trunc {
                            let t = (sdf * inv_trunc).min(1.0);
                            let w0 = v.weight;
                            let w1 = w0 + 1.0;
                            v.tsdf = (v.tsdf * w0 + t) / w1;
                            v.weight = w1.min(max_w);
                        }
                    }
                }
                for a in 0..3 {
                    p[a] += dx[a];
                }
            }
        }
    }
}
