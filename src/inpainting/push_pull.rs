//! Push–pull depth fill: a weighted image pyramid averages known depths down, then fills unknown pixels
//! from coarser levels on the way back up.

use super::{InpaintContext, Inpainter};
use crate::geometry::DepthMap;

/// The classical fill (Gortler et al.'s push–pull): every unknown pixel gets a smooth weighted average of
/// the known depths around it, at the scale where known depths first appear (pulled back up with
/// bilinear interpolation). Known pixels are copied.
#[derive(Clone, Copy, Debug, Default)]
pub struct PushPull;

struct Level {
    w: usize,
    h: usize,
    /// Weighted depth sum and weight per pixel.
    zw: Vec<f32>,
    wt: Vec<f32>,
}

impl Inpainter for PushPull {
    fn name(&self) -> &'static str {
        "push_pull"
    }

    fn inpaint(&self, depth: &DepthMap, known: &[bool], _: &InpaintContext) -> DepthMap {
        let (w, h) = (depth.width() as usize, depth.height() as usize);
        let d = depth.data();
        let mut levels = vec![Level {
            w,
            h,
            zw: d.iter().zip(known).map(|(&z, &k)| if k && z > 0.0 { z } else { 0.0 }).collect(),
            wt: d.iter().zip(known).map(|(&z, &k)| if k && z > 0.0 { 1.0 } else { 0.0 }).collect(),
        }];
        // Push: 2×2 box reduction, weights clamped to 1 so dense regions do not dominate.
        while levels.last().map(|l| l.w > 1 || l.h > 1).unwrap_or(false) {
            let l = levels.last().unwrap();
            let (nw, nh) = (l.w.div_ceil(2), l.h.div_ceil(2));
            let mut zw = vec![0.0f32; nw * nh];
            let mut wt = vec![0.0f32; nw * nh];
            for r in 0..nh {
                for c in 0..nw {
                    let (mut sz, mut sw) = (0.0f32, 0.0f32);
                    for (dr, dc) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                        let (rr, cc) = (2 * r + dr, 2 * c + dc);
                        if rr < l.h && cc < l.w {
                            sz += l.zw[rr * l.w + cc];
                            sw += l.wt[rr * l.w + cc];
                        }
                    }
                    let scale = if sw > 1.0 { 1.0 / sw } else { 1.0 };
                    zw[r * nw + c] = sz * scale;
                    wt[r * nw + c] = sw * scale;
                }
            }
            levels.push(Level { w: nw, h: nh, zw, wt });
        }
        // Pull: fill each level's missing weight from the coarser level, interpolated bilinearly at the
        // fine pixel's centre (premultiplied depth and weight, so empty coarse pixels do not pull to 0).
        for i in (0..levels.len() - 1).rev() {
            let (coarse, fine) = {
                let (a, b) = levels.split_at_mut(i + 1);
                (&b[0], &mut a[i])
            };
            for r in 0..fine.h {
                let (r0, r1, fr) = bilinear_taps(r, coarse.h);
                for c in 0..fine.w {
                    let j = r * fine.w + c;
                    let wt = fine.wt[j];
                    if wt >= 1.0 {
                        continue;
                    }
                    let (c0, c1, fc) = bilinear_taps(c, coarse.w);
                    let (mut zw, mut w) = (0.0f32, 0.0f32);
                    for (rr, wr) in [(r0, 1.0 - fr), (r1, fr)] {
                        for (cc, wc) in [(c0, 1.0 - fc), (c1, fc)] {
                            let k = rr * coarse.w + cc;
                            let a = wr * wc;
                            zw += a * coarse.zw[k];
                            w += a * coarse.wt[k];
                        }
                    }
                    if w > 0.0 {
                        fine.zw[j] += (1.0 - wt) * zw / w;
                        fine.wt[j] = 1.0;
                    }
                }
            }
        }
        let top = &levels[0];
        let out: Vec<f32> = (0..w * h)
            .map(|j| {
                if known[j] {
                    d[j]
                } else if top.wt[j] > 0.0 {
                    top.zw[j] / top.wt[j]
                } else {
                    0.0
                }
            })
            .collect();
        DepthMap::new(depth.width(), depth.height(), out).expect("averages of valid depths are valid")
    }
}

/// The two coarse indices around fine index `i` (centre `(i + ½)/2 − ½` in coarse pixels, clamped) and
/// the weight of the second.
fn bilinear_taps(i: usize, coarse_len: usize) -> (usize, usize, f32) {
    let x = ((i as f32 + 0.5) * 0.5 - 0.5).clamp(0.0, (coarse_len - 1) as f32);
    let i0 = x.floor() as usize;
    let i1 = (i0 + 1).min(coarse_len - 1);
    (i0, i1, x - i0 as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn keeps_known_pixels_bit_exact_and_fills_everything_reachable() {
        let mut r = Rng::new(3);
        let (w, h) = (64u32, 48u32);
        let data: Vec<f32> = (0..w * h).map(|_| r.uniform_range(0.5, 5.0) as f32).collect();
        let known: Vec<bool> = (0..w * h).map(|_| r.uniform() < 0.3).collect();
        let d = DepthMap::new(w, h, data.clone()).unwrap();
        let out = PushPull.inpaint(&d, &known, &super::super::test_context(&d));
        for i in 0..(w * h) as usize {
            if known[i] {
                assert_eq!(out.data()[i].to_bits(), data[i].to_bits());
            } else {
                assert!(out.data()[i] >= 0.5 && out.data()[i] <= 5.0, "fill stays within the known range");
            }
        }
    }

    #[test]
    fn fills_a_hole_in_a_plane_with_the_plane_depth() {
        let (w, h) = (32u32, 32u32);
        let data = vec![2.0f32; (w * h) as usize];
        let known: Vec<bool> = (0..w * h).map(|i| !((10..20).contains(&(i % w)) && (10..20).contains(&(i / w)))).collect();
        let out = { let d = DepthMap::new(w, h, data).unwrap(); PushPull.inpaint(&d, &known, &super::super::test_context(&d)) };
        assert!(out.data().iter().all(|z| (*z - 2.0).abs() < 1e-6));
    }

    #[test]
    fn a_hole_in_a_ramp_is_filled_smoothly() {
        // Depth rising linearly along x with a 20-pixel hole: the fill stays near the ramp (no blocks).
        let (w, h) = (64u32, 32u32);
        let data: Vec<f32> = (0..w * h).map(|i| 1.0 + 0.01 * (i % w) as f32).collect();
        let known: Vec<bool> = (0..w * h).map(|i| !(20..40).contains(&(i % w))).collect();
        let out = { let d = DepthMap::new(w, h, data.clone()).unwrap(); PushPull.inpaint(&d, &known, &super::super::test_context(&d)) };
        let worst = out.data().iter().zip(&data).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(worst < 0.06, "largest deviation from the ramp {worst}");
        // Neighbouring filled pixels never jump by more than a few ramp steps.
        for r in 0..h {
            for c in 20..40u32 {
                let i = (r * w + c) as usize;
                assert!((out.data()[i] - out.data()[i - 1]).abs() < 0.02, "step at ({c},{r})");
            }
        }
    }

    #[test]
    fn nothing_known_stays_empty() {
        let d = DepthMap::zeros(8, 8);
        let out = PushPull.inpaint(&d, &[false; 64], &super::super::test_context(&d));
        assert!(out.data().iter().all(|z| *z == 0.0));
    }
}
