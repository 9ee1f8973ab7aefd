//! Network space: the one place where metric depth becomes a network value and back.
//!
//! The authors' networks read depth divided by 10 m ([`DEPTH_SCALE_M`]): the correction network takes
//! `z / 10` in [0, 1] ([`normalise_depth`], reference §4.2), the diffusion model `2·z/10 − 1` in [−1, 1]
//! ([`to_network`] / [`from_network`], reference §3.1, §5.3). Missing depth is 0 and −1 respectively.

/// Metres per unit of the networks' depth input (1.0 = 10 m; deeper is treated as missing).
pub const DEPTH_SCALE_M: f32 = 10.0;

/// The correction network's input value of a metric depth: `z / 10`, with missing, non-finite and
/// > 10 m as 0.
pub fn normalise_depth(z: f32) -> f32 {
    let v = z / DEPTH_SCALE_M;
    if v.is_finite() && v > 0.0 && v <= 1.0 {
        v
    } else {
        0.0
    }
}

/// The diffusion model's value of a metric depth: `2·z/10 − 1`, with missing, non-finite and > 10 m as −1.
pub fn to_network(z: f32) -> f32 {
    2.0 * normalise_depth(z) - 1.0
}

/// Metric depth of a diffusion-model value (the inverse of [`to_network`] on (−1, 1]; −1 and below is
/// missing, 0 m).
pub fn from_network(v: f32) -> f32 {
    if v > -1.0 {
        (v + 1.0) * 0.5 * DEPTH_SCALE_M
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn network_space_round_trips_and_marks_missing_depth() {
        for z in [0.5f32, 1.234, 3.0, 9.99] {
            assert!((from_network(to_network(z)) - z).abs() < 1e-5);
            assert!((normalise_depth(z) - z / 10.0).abs() < 1e-7);
        }
        for z in [0.0f32, -1.0, 11.0, f32::NAN, f32::INFINITY] {
            assert_eq!(normalise_depth(z), 0.0);
            assert_eq!(to_network(z), -1.0);
            assert_eq!(from_network(to_network(z)), 0.0);
        }
        assert_eq!(to_network(10.0), 1.0);
        assert_eq!(from_network(-1.5), 0.0);
    }
}
