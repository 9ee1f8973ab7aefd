//! The projective TSDF update of one block, in portable scalar code and an AVX2 kernel that gives
//! bit-identical results (same operations in the same order, no fused multiply-add).

use super::camera::Camera;
use super::volume::Voxel;

/// What one integration applies to every touched block.
#[derive(Clone, Copy, Debug)]
pub(crate) struct UpdateParams {
    /// Voxels per block side.
    pub(crate) side: usize,
    /// Voxel edge, metres.
    pub(crate) voxel: f32,
    /// Truncation, metres.
    pub(crate) trunc: f32,
    /// Weight cap.
    pub(crate) max_weight: f32,
    /// Whether to use the AVX2 kernel (rows of 8 voxels; detected at run time).
    pub(crate) avx2: bool,
}

impl UpdateParams {
    pub(crate) fn new(side: usize, voxel: f32, trunc: f32, max_weight: f32) -> Self {
        #[cfg(target_arch = "x86_64")]
        let avx2 = side % 8 == 0 && std::is_x86_feature_detected!("avx2");
        #[cfg(not(target_arch = "x86_64"))]
        let avx2 = false;
        UpdateParams { side, voxel, trunc, max_weight, avx2 }
    }
}

/// Updates the voxels `vox` of block `b` with the depth image `depth` (row-major metres, 0 where
/// invalid or out of range) seen by `cam`: see [`super::TsdfVolume::integrate`].
pub(crate) fn update_block(vox: &mut [Voxel], b: [i32; 3], cam: &Camera, depth: &[f32], p: &UpdateParams) {
    let side = p.side;
    let n = side as i32;
    let origin = [0, 1, 2].map(|a| ((b[a] * n) as f32 + 0.5) * p.voxel);
    let base = cam.camera_point(origin);
    // Camera-frame steps of one voxel along world x, y, z: columns of R scaled.
    let step = |j: usize| [cam.r[0][j] * p.voxel, cam.r[1][j] * p.voxel, cam.r[2][j] * p.voxel];
    let (dx, dy, dz) = (step(0), step(1), step(2));
    for (zi, plane) in vox.chunks_exact_mut(side * side).enumerate() {
        for (yi, row) in plane.chunks_exact_mut(side).enumerate() {
            let (fz, fy) = (zi as f32, yi as f32);
            let start = [0, 1, 2].map(|a| base[a] + dz[a] * fz + dy[a] * fy);
            // Runs of 8 voxels start at `start + dx·8i`, then step by `dx`: the AVX2 kernel's
            // arithmetic, so both paths give the same bits.
            for (i, run) in row.chunks_mut(8).enumerate() {
                let s = [0, 1, 2].map(|a| start[a] + dx[a] * (8 * i) as f32);
                #[cfg(target_arch = "x86_64")]
                if p.avx2 && run.len() == 8 {
                    // SAFETY: `avx2` is set only when the CPU has AVX2; `run` has 8 voxels.
                    unsafe { avx2::update8(run, s, dx, cam, depth, p) };
                    continue;
                }
                for (j, v) in run.iter_mut().enumerate() {
                    let fj = j as f32;
                    update_voxel(v, [0, 1, 2].map(|a| s[a] + dx[a] * fj), cam, depth, p);
                }
            }
        }
    }
}

/// The update of one voxel whose centre is `q` in camera coordinates (metres).
#[inline]
pub(crate) fn update_voxel(v: &mut Voxel, q: [f32; 3], cam: &Camera, depth: &[f32], p: &UpdateParams) {
    let z = q[2];
    let inv_z = 1.0 / z;
    let u = cam.fx * q[0] * inv_z + cam.cx + 0.5;
    let r = cam.fy * q[1] * inv_z + cam.cy + 0.5;
    if !(z > 0.0 && u >= 0.0 && u < cam.width as f32 && r >= 0.0 && r < cam.height as f32) {
        return;
    }
    // SAFETY: 0 ≤ u < width and 0 ≤ r < height (checked above), so both fit a usize.
    let (u, r) = unsafe { (u.to_int_unchecked::<usize>(), r.to_int_unchecked::<usize>()) };
    let d = depth[r * cam.width + u];
    let sdf = d - z;
    if d > 0.0 && sdf >= -p.trunc {
        let t = (sdf * (1.0 / p.trunc)).min(1.0);
        let w0 = v.weight;
        let w1 = w0 + 1.0;
        v.tsdf = (v.tsdf * w0 + t) / w1;
        v.weight = w1.min(p.max_weight);
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{Camera, UpdateParams, Voxel};
    use std::arch::x86_64::*;

    /// [`super::update_voxel`] on 8 consecutive voxels of a row, the first at camera point `s`,
    /// each next one `dx` further.
    ///
    /// # Safety
    /// The CPU must support AVX2, and `vox` must hold exactly 8 voxels.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn update8(
        vox: &mut [Voxel],
        s: [f32; 3],
        dx: [f32; 3],
        cam: &Camera,
        depth: &[f32],
        p: &UpdateParams,
    ) {
        assert_eq!(vox.len(), 8);
        // Lane order 0 1 4 5 | 2 3 6 7: what the de-interleaving shuffles below produce.
        let idx = _mm256_setr_ps(0.0, 1.0, 4.0, 5.0, 2.0, 3.0, 6.0, 7.0);
        let at = |a: usize| _mm256_add_ps(_mm256_set1_ps(s[a]), _mm256_mul_ps(_mm256_set1_ps(dx[a]), idx));
        let (x, y, z) = (at(0), at(1), at(2));
        let zero = _mm256_setzero_ps();
        let inv_z = _mm256_div_ps(_mm256_set1_ps(1.0), z);
        let half = _mm256_set1_ps(0.5);
        let proj = |f: f32, c: f32, v: __m256| {
            _mm256_add_ps(
                _mm256_add_ps(_mm256_mul_ps(_mm256_mul_ps(_mm256_set1_ps(f), v), inv_z), _mm256_set1_ps(c)),
                half,
            )
        };
        let (u, r) = (proj(cam.fx, cam.cx, x), proj(cam.fy, cam.cy, y));
        let inside = _mm256_and_ps(
            _mm256_and_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(z, zero), _mm256_cmp_ps::<_CMP_GE_OQ>(u, zero)),
            _mm256_and_ps(
                _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_LT_OQ>(u, _mm256_set1_ps(cam.width as f32)),
                    _mm256_cmp_ps::<_CMP_GE_OQ>(r, zero),
                ),
                _mm256_cmp_ps::<_CMP_LT_OQ>(r, _mm256_set1_ps(cam.height as f32)),
            ),
        );
        if _mm256_movemask_ps(inside) == 0 {
            return;
        }
        let pixel = _mm256_add_epi32(
            _mm256_mullo_epi32(_mm256_cvttps_epi32(r), _mm256_set1_epi32(cam.width as i32)),
            _mm256_cvttps_epi32(u),
        );
        // Only lanes inside the image load; the others read nothing and stay 0.
        let d = _mm256_mask_i32gather_ps::<4>(zero, depth.as_ptr(), pixel, inside);
        let sdf = _mm256_sub_ps(d, z);
        let update = _mm256_and_ps(
            _mm256_and_ps(inside, _mm256_cmp_ps::<_CMP_GT_OQ>(d, zero)),
            _mm256_cmp_ps::<_CMP_GE_OQ>(sdf, _mm256_set1_ps(-p.trunc)),
        );
        if _mm256_movemask_ps(update) == 0 {
            return;
        }
        let t = _mm256_min_ps(_mm256_mul_ps(sdf, _mm256_set1_ps(1.0 / p.trunc)), _mm256_set1_ps(1.0));
        let ptr = vox.as_mut_ptr() as *mut f32;
        // [t0 w0 t1 w1 | t2 w2 t3 w3] and [t4 w4 t5 w5 | t6 w6 t7 w7].
        let (lo, hi) = (_mm256_loadu_ps(ptr), _mm256_loadu_ps(ptr.add(8)));
        let tsdf = _mm256_shuffle_ps::<0x88>(lo, hi); // t0 t1 t4 t5 | t2 t3 t6 t7
        let w0 = _mm256_shuffle_ps::<0xDD>(lo, hi); // w0 w1 w4 w5 | w2 w3 w6 w7
        let w1 = _mm256_add_ps(w0, _mm256_set1_ps(1.0));
        let new_t = _mm256_div_ps(_mm256_add_ps(_mm256_mul_ps(tsdf, w0), t), w1);
        let new_w = _mm256_min_ps(w1, _mm256_set1_ps(p.max_weight));
        let tsdf = _mm256_blendv_ps(tsdf, new_t, update);
        let w = _mm256_blendv_ps(w0, new_w, update);
        _mm256_storeu_ps(ptr, _mm256_unpacklo_ps(tsdf, w));
        _mm256_storeu_ps(ptr.add(8), _mm256_unpackhi_ps(tsdf, w));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Intrinsics;
    use crate::rng::Rng;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    #[test]
    fn avx2_and_scalar_kernels_agree_bit_for_bit() {
        let k = Intrinsics::new(150.0, 140.0, 80.5, 59.5, 160, 120).unwrap();
        let pose = Isometry3::from_parts(
            Translation3::new(0.05, -0.1, -0.2),
            UnitQuaternion::from_euler_angles(0.1, 0.2, -0.05),
        );
        let cam = Camera::new(&k, &pose);
        let mut rng = Rng::new(5);
        let depth: Vec<f32> = (0..160 * 120)
            .map(|_| if rng.uniform() < 0.1 { 0.0 } else { rng.uniform_range(0.3, 0.9) as f32 })
            .collect();
        let scalar = UpdateParams { avx2: false, ..UpdateParams::new(8, 0.01, 0.04, 3.0) };
        let simd = UpdateParams::new(8, 0.01, 0.04, 3.0);
        if !simd.avx2 {
            eprintln!("note: no AVX2 on this CPU; only the scalar kernel runs");
        }
        let mut updated = 0;
        for b in [[0, 0, 2], [-1, 0, 3], [1, -1, 4], [0, 1, 5], [-2, -2, 2]] {
            let mut a = vec![Voxel { tsdf: 0.3, weight: 1.0 }; 512];
            let mut c = a.clone();
            for _ in 0..4 {
                update_block(&mut a, b, &cam, &depth, &scalar);
                update_block(&mut c, b, &cam, &depth, &simd);
            }
            assert!(
                a.iter().zip(&c).all(|(x, y)| x.tsdf.to_bits() == y.tsdf.to_bits() && x.weight == y.weight),
                "block {b:?}"
            );
            updated += a.iter().filter(|v| v.weight > 1.0).count();
        }
        assert!(updated > 500, "{updated}");
    }
}
