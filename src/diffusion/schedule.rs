//! The noise schedule (reference §5.2): the sigmoid β schedule of arXiv:2212.11972, its ᾱ, SNR and the
//! DDIM step pairs.

/// ᾱ and β of a discrete schedule of `T` steps (f64, as the reference computes them before casting).
#[derive(Clone, Debug, PartialEq)]
pub struct Schedule {
    pub betas: Vec<f64>,
    pub alphas_cumprod: Vec<f64>,
}

fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

impl Schedule {
    /// The reference's schedule: `sigmoid_beta_schedule(T = 1000, start = −3, end = 3, τ = 1)`.
    pub fn official() -> Self {
        Self::sigmoid(1000, -3.0, 3.0, 1.0)
    }

    /// `ᾱ(t) = (σ(end/τ) − σ((t·(end − start) + start)/τ)) / (σ(end/τ) − σ(start/τ))` on `t = i/T`,
    /// normalised by `ᾱ(0)`; `β_i = clip(1 − ᾱ(i+1)/ᾱ(i), 0, 0.999)`; `ᾱ_i = Π_{j ≤ i} (1 − β_j)`.
    pub fn sigmoid(timesteps: usize, start: f64, end: f64, tau: f64) -> Self {
        let (v_start, v_end) = (sigmoid(start / tau), sigmoid(end / tau));
        let curve: Vec<f64> = (0..=timesteps)
            .map(|i| {
                let t = i as f64 / timesteps as f64;
                (v_end - sigmoid((t * (end - start) + start) / tau)) / (v_end - v_start)
            })
            .collect();
        let betas: Vec<f64> = curve.windows(2).map(|w| (1.0 - w[1] / w[0]).clamp(0.0, 0.999)).collect();
        let mut acc = 1.0;
        let alphas_cumprod = betas
            .iter()
            .map(|b| {
                acc *= 1.0 - b;
                acc
            })
            .collect();
        Schedule { betas, alphas_cumprod }
    }

    /// Number of steps T.
    pub fn len(&self) -> usize {
        self.betas.len()
    }

    pub fn is_empty(&self) -> bool {
        self.betas.is_empty()
    }

    /// ᾱ_t; by convention ᾱ₋₁ = 1 (the clean image).
    pub fn alpha_bar(&self, t: i64) -> f64 {
        if t < 0 {
            1.0
        } else {
            self.alphas_cumprod[t as usize]
        }
    }

    /// Signal-to-noise ratio `ᾱ_t / (1 − ᾱ_t)`: the official x0-objective loss weight.
    pub fn snr(&self, t: usize) -> f64 {
        let a = self.alphas_cumprod[t];
        a / (1.0 - a)
    }

    /// DDIM's `(t, t_next)` pairs for `steps` sampling steps: `int(linspace(−1, T − 1, steps + 1))`
    /// reversed (truncation towards zero, as the reference's `.int()`); 250 of 1000 gives
    /// `(999, 995), (995, 991), …, (3, −1)`.
    pub fn ddim_pairs(&self, steps: usize) -> Vec<(i64, i64)> {
        self.ddim_pairs_from(self.len() - 1, steps)
    }

    /// DDIM pairs from step `start` (instead of T − 1) down to −1: `int(linspace(−1, start, steps + 1))`.
    /// At most `start + 1` pairs: a larger `steps` is clamped (configs refuse it, see
    /// [`crate::inpainting::DiffusionInpaintConfig::validate`]).
    pub fn ddim_pairs_from(&self, start: usize, steps: usize) -> Vec<(i64, i64)> {
        let t_max = start.min(self.len() - 1) as f64;
        let steps = steps.clamp(1, t_max as usize + 1);
        let times: Vec<i64> = (0..=steps)
            .rev()
            .map(|k| {
                let v = -1.0 + k as f64 * (t_max + 1.0) / steps as f64;
                // Values meant to be integers must not fall just below them.
                let r = v.round();
                if (v - r).abs() < 1e-9 {
                    r as i64
                } else {
                    v.trunc() as i64
                }
            })
            .collect();
        times.windows(2).map(|w| (w[0], w[1])).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_official_schedule_has_the_reference_values() {
        let s = Schedule::official();
        assert_eq!(s.len(), 1000);
        // Reference §5.2: β0 ≈ 3.0e-4, β999 = 0.999 (clipped), ᾱ0 ≈ 0.99970, ᾱ499 = 0.5, ᾱ999 ≈ 3.0e-7.
        assert!((s.betas[0] - 3.0e-4).abs() < 0.05e-4, "{}", s.betas[0]);
        assert_eq!(s.betas[999], 0.999);
        assert!((s.alphas_cumprod[0] - 0.99970).abs() < 5e-6);
        assert!((s.alphas_cumprod[499] - 0.5).abs() < 1e-9, "{}", s.alphas_cumprod[499]);
        assert!((s.alphas_cumprod[999] / 3.0e-7 - 1.0).abs() < 0.05, "{}", s.alphas_cumprod[999]);
        // Reference §5.3 SNR weights: ≈ 3329 at t = 0, ≈ 24 at t = 100, ≈ 1 at t = 500.
        assert!((s.snr(0) / 3329.0 - 1.0).abs() < 0.01, "{}", s.snr(0));
        assert!((s.snr(100) / 24.0 - 1.0).abs() < 0.05, "{}", s.snr(100));
        assert!((s.snr(500) - 1.0).abs() < 0.05);
        assert!(s.alphas_cumprod.windows(2).all(|w| w[1] < w[0]));
    }

    #[test]
    fn ddim_pairs_follow_the_reference_linspace() {
        let s = Schedule::official();
        let p = s.ddim_pairs(250);
        assert_eq!(p.len(), 250);
        assert_eq!(p[0], (999, 995));
        assert_eq!(p[1], (995, 991));
        assert_eq!(p[249], (3, -1));
        // A step count that does not divide T: linspace(−1, 999, 4) = −1, 332.33, 665.67, 999.
        assert_eq!(s.ddim_pairs(3), vec![(999, 665), (665, 332), (332, -1)]);
        assert_eq!(s.ddim_pairs(1), vec![(999, -1)]);
        assert_eq!(s.ddim_pairs_from(499, 5), vec![(499, 399), (399, 299), (299, 199), (199, 99), (99, -1)]);
    }
}
