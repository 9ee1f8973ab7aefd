//! Colour maps: Google's Turbo (its published polynomial approximation) for depth, and the fixed
//! colours every preview uses.

use super::canvas::Rgb;

/// Invalid depth (0 in the PNG).
pub const INVALID: Rgb = [0, 0, 0];
/// Unknown pixels of the condition (not re-projected): a grey, which Turbo never produces.
pub const UNKNOWN: Rgb = [150, 150, 150];
/// Background of montages and plots.
pub const BACKGROUND: Rgb = [32, 32, 36];
/// Text.
pub const TEXT: Rgb = [235, 235, 235];
/// The source cloud, the target cloud, and pixels both cover with depths less than 5 cm apart
/// (`montage::BOTH_METRES`).
pub const SOURCE: Rgb = [255, 64, 32];
pub const TARGET: Rgb = [40, 220, 60];
pub const BOTH: Rgb = [255, 230, 40];

/// Turbo at `x` in [0, 1] (clamped): blue → cyan → green → yellow → red. The darkest 5 % of the map
/// are left out (`x` maps to Turbo's `0.05 + 0.95·x`), so the nearest depth stays distinct from the
/// black of invalid pixels.
pub fn turbo(x: f32) -> Rgb {
    let x = 0.05 + 0.95 * if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) } as f64;
    let (x2, x3) = (x * x, x * x * x);
    let (x4, x5) = (x2 * x2, x2 * x3);
    let r = 0.13572138 + 4.61539260 * x - 42.66032258 * x2 + 132.13108234 * x3 - 152.94239396 * x4 + 59.28637943 * x5;
    let g = 0.09140261 + 2.19418839 * x + 4.84296658 * x2 - 14.18503333 * x3 + 4.27729857 * x4 + 2.82956604 * x5;
    let b = 0.10667330 + 12.64194608 * x - 60.58204836 * x2 + 110.36276771 * x3 - 89.90310912 * x4 + 27.34824973 * x5;
    [r, g, b].map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
}

/// `c` darkened by `factor` in [0, 1] (1 = unchanged).
pub fn shade(c: Rgb, factor: f32) -> Rgb {
    c.map(|v| (v as f32 * factor.clamp(0.0, 1.0)).round() as u8)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turbo_runs_from_blue_through_green_to_red() {
        let lo = turbo(0.0);
        let mid = turbo(0.5);
        let hi = turbo(1.0);
        assert!(lo[2] > lo[0] && lo[2] > lo[1], "{lo:?}");
        assert!(mid[1] > 200, "{mid:?}");
        assert!(hi[0] > hi[1] && hi[0] > hi[2], "{hi:?}");
        assert_eq!(turbo(-3.0), lo);
        assert_eq!(turbo(f32::NAN), lo);
        // No Turbo colour is a grey, so unknown pixels stand out.
        assert!((0..=100).map(|i| turbo(i as f32 / 100.0)).all(|c| c.iter().max().unwrap() - c.iter().min().unwrap() > 40));
        assert_eq!(shade([200, 100, 0], 0.5), [100, 50, 0]);
    }
}
