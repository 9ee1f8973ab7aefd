//! DepthAugment (reference §4.1): the depth, its 3×3 minimum over valid neighbours and the residual, as
//! the correction network's three input channels.

use tch::Tensor;

/// 3×3 minimum over the valid (> 0) depths of each pixel's neighbourhood (itself included; outside the
/// image counts as missing); where all nine are invalid, the official fallback: the plain 3×3 minimum,
/// which is 0.
///
/// Shapes: `d [B, 1, H, W]` → `[B, 1, H, W]`.
pub fn valid_min3x3(d: &Tensor) -> Tensor {
    let d_inf = d.masked_fill(&d.eq(0.0), f64::INFINITY);
    // max_pool2d pads with −inf, i.e. +inf after the negations: padding never wins the minimum.
    let mn = -(-d_inf).max_pool2d([3, 3], [1, 1], [1, 1], [1, 1], false);
    let mn0 = -(-d).max_pool2d([3, 3], [1, 1], [1, 1], [1, 1], false);
    mn0.where_self(&mn.isinf(), &mn)
}

/// `cat[d, mn, mn − d]` with `mn` = [`valid_min3x3`]: the residual is ≤ 0 on valid pixels (how far a
/// depth lies behind its nearest neighbour) and > 0 on holes next to depth.
///
/// Shapes: `d [B, 1, H, W]` → `[B, 3, H, W]`.
pub fn depth_augment(d: &Tensor) -> Tensor {
    let mn = valid_min3x3(d);
    let res = &mn - d;
    Tensor::cat(&[d, &mn, &res], 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::DepthMap;
    use crate::rng::Rng;

    #[test]
    fn matches_the_brute_force_min_pool_with_the_official_fallback() {
        let mut r = Rng::new(9);
        let (w, h) = (19usize, 13usize);
        for hole_rate in [0.2, 0.6, 0.95] {
            let data: Vec<f32> = (0..w * h)
                .map(|_| if r.uniform() < hole_rate { 0.0 } else { r.uniform_range(0.05, 1.0) as f32 })
                .collect();
            let t = Tensor::from_slice(&data).view([1, 1, h as i64, w as i64]);
            let got: Vec<f32> = Vec::try_from(depth_augment(&t).flatten(0, -1)).unwrap();
            let expect_min =
                crate::geometry::valid_min3x3(&DepthMap::new(w as u32, h as u32, data.clone()).unwrap());
            for i in 0..w * h {
                let m = if expect_min[i].is_finite() { expect_min[i] } else { 0.0 };
                assert_eq!(got[i], data[i]);
                assert_eq!(got[w * h + i], m, "pixel {i}");
                assert_eq!(got[2 * w * h + i], m - data[i]);
            }
        }
    }
}
