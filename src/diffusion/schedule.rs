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

fn sigmoid_f32(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

impl Schedule {
    /// The reference's schedule: `sigmoid_beta_schedule(T = 1000, start = −3, end = 3, τ = 1)`.
    pub fn official() -> Self {
        Self::sigmoid(1000, -3.0, 3.0, 1.0)
    }

    /// `ᾱ(t) = (σ(end/τ) − σ((t·(end − start) + start)/τ)) / (σ(end/τ) − σ(start/τ))` on `t = i/T`,
    /// normalised by `ᾱ(0)`; `β_i = clip(1 − ᾱ(i+1)/ᾱ(i), 0, 0.999)`; `ᾱ_i = Π_{j ≤ i} (1 − β_j)`.
    ///
    /// In the reference's precision: the end points `σ(start/τ)`, `σ(end/τ)` and their difference are
    /// float32 (`torch.tensor(start / tau).sigmoid()`), everything else float64. Against an all-f64
    /// computation β differs by < 1e-6 (relative) up to t = 975 and by up to 1.3e-5 above.
    pub fn sigmoid(timesteps: usize, start: f64, end: f64, tau: f64) -> Self {
        let (v_start, v_end) = (sigmoid_f32((start / tau) as f32), sigmoid_f32((end / tau) as f32));
        let span = f64::from(v_end - v_start);
        let curve: Vec<f64> = (0..=timesteps)
            .map(|i| {
                let t = i as f64 / timesteps as f64;
                (f64::from(v_end) - sigmoid((t * (end - start) + start) / tau)) / span
            })
            .collect();
        let curve: Vec<f64> = curve.iter().map(|c| c / curve[0]).collect();
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
        assert!((s.alphas_cumprod[499] - 0.5).abs() < 1e-8, "{}", s.alphas_cumprod[499]);
        assert!((s.alphas_cumprod[999] / 3.0e-7 - 1.0).abs() < 0.05, "{}", s.alphas_cumprod[999]);
        // Reference §5.3 SNR weights: ≈ 3329 at t = 0, ≈ 24 at t = 100, ≈ 1 at t = 500.
        assert!((s.snr(0) / 3329.0 - 1.0).abs() < 0.01, "{}", s.snr(0));
        assert!((s.snr(100) / 24.0 - 1.0).abs() < 0.05, "{}", s.snr(100));
        assert!((s.snr(500) - 1.0).abs() < 0.05);
        assert!(s.alphas_cumprod.windows(2).all(|w| w[1] < w[0]));
    }

    /// β_t and ᾱ_t of the authors' `sigmoid_beta_schedule(1000)` as PyTorch 2.13 computes them (float32 end
    /// points, float64 rest), printed by `benchmarks/peers/schedule_peer.py`. The f64 values agree to the
    /// bit at these steps and within 2e-13 (relative) at all (PyTorch's vectorised f64 `exp` is 1 ulp off
    /// libm's at a few t); the float32 buffers the authors keep agree at every step.
    const PYTORCH: [(usize, f64, f64); 11] = [
        (0, 0.0003002791974102692, 0.9996997208025897),
        (1, 0.00030200411683434236, 0.9993978073713092),
        (19, 0.00033471175588328794, 0.9936747785207053),
        (499, 0.003303415462333259, 0.5000000038946949),
        (500, 0.0033143641842271476, 0.4983428217896729),
        (974, 0.04109965340073518, 0.008015759852813898),
        (975, 0.04263280344550813, 0.0076740255385424885),
        (976, 0.044293800505199155, 0.007334113782266484),
        (990, 0.10245167352769313, 0.0027620198333537555),
        (998, 0.5013504179271411, 0.00030028698679996615),
        (999, 0.999, 3.002869867999664e-07),
    ];

    #[test]
    fn the_paper_schedule_matches_pytorch() {
        let s = Schedule::official();
        for (t, beta, alpha_bar) in PYTORCH {
            assert_eq!((t, s.betas[t], s.alphas_cumprod[t]), (t, beta, alpha_bar));
        }
        // Σ (t + 1)·bits(f32(v_t)) over all 1000 steps, printed by the same script.
        let checksum = |v: &[f64]| (1..).zip(v).map(|(w, &x)| w * u64::from((x as f32).to_bits())).sum::<u64>();
        assert_eq!(checksum(&s.betas), 502059814767421);
        assert_eq!(checksum(&s.alphas_cumprod), 521115305101333);
    }

    #[test]
    fn float32_end_points_move_beta_above_step_975_by_the_stated_amount() {
        // The same formula all in f64 (what the schedule computed before).
        let sig = |x: f64| 1.0 / (1.0 + (-x).exp());
        let (v0, v1) = (sig(-3.0), sig(3.0));
        let curve: Vec<f64> = (0..=1000).map(|i| (v1 - sig(i as f64 / 1000.0 * 6.0 - 3.0)) / (v1 - v0)).collect();
        let f64_betas: Vec<f64> = curve.windows(2).map(|w| (1.0 - w[1] / w[0]).clamp(0.0, 0.999)).collect();
        let rel: Vec<f64> =
            Schedule::official().betas.iter().zip(&f64_betas).map(|(a, b)| (a - b).abs() / b).collect();
        let max = |r: &[f64]| r.iter().cloned().fold(0.0, f64::max);
        assert!(max(&rel[..20]) < 1e-8, "{}", max(&rel[..20]));
        assert!(max(&rel[..976]) < 1e-6, "{}", max(&rel[..976]));
        assert!(rel[976..999].iter().all(|&r| r > 1e-6));
        assert!((max(&rel) - 1.3e-5).abs() < 0.05e-5, "{}", max(&rel));
        assert_eq!(rel[999], 0.0, "clipped at 0.999 either way");
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
