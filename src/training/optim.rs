//! The trainers' optimiser and weight average, written out so their state can be checkpointed: Adam with
//! bias correction and gradient-norm clipping (the denoiser's and the descriptor's), and the EMA of
//! ema_pytorch 0.2.2 (the denoiser's, reference §5.3).

use crate::diffusion::checkpoint::Named;
use tch::{Kind, Tensor};

/// Adam (Kingma & Ba) with bias correction, on a fixed list of variables.
pub struct Adam {
    pub lr: f64,
    pub betas: (f64, f64),
    pub eps: f64,
    pub m: Named,
    pub v: Named,
}

impl Adam {
    pub fn new(vars: &[(String, Tensor)], lr: f64, betas: (f64, f64)) -> Self {
        let zeros = |v: &[(String, Tensor)]| v.iter().map(|(k, t)| (k.clone(), t.zeros_like())).collect();
        Adam { lr, betas, eps: 1e-8, m: zeros(vars), v: zeros(vars) }
    }

    /// Scales the gradients to a total norm of at most `clip` (as `clip_grad_norm_`), then takes step
    /// number `step` (1-based). Returns the norm before clipping.
    pub fn step(&mut self, vars: &[(String, Tensor)], step: u64, clip: f64) -> f64 {
        tch::no_grad(|| {
            let grads: Vec<Tensor> = vars.iter().map(|(_, p)| p.grad()).collect();
            let norm: f64 = grads
                .iter()
                .filter(|g| g.defined())
                .map(|g| g.pow_tensor_scalar(2).sum(Kind::Double).double_value(&[]))
                .sum::<f64>()
                .sqrt();
            let scale = (clip / (norm + 1e-6)).min(1.0);
            let (b1, b2) = self.betas;
            let (c1, c2) = (1.0 - b1.powi(step as i32), 1.0 - b2.powi(step as i32));
            for (((_, p), g), ((_, m), (_, v))) in vars.iter().zip(&grads).zip(self.m.iter().zip(&self.v)) {
                if !g.defined() {
                    continue;
                }
                let g = g * scale;
                let _ = m.shallow_clone().g_mul_scalar_(b1).g_add_(&(&g * (1.0 - b1)));
                let _ = v.shallow_clone().g_mul_scalar_(b2).g_add_(&(g.square() * (1.0 - b2)));
                let update = (m / c1) / ((v / c2).sqrt() + self.eps) * self.lr;
                let _ = p.shallow_clone().g_sub_(&update);
            }
            for (_, p) in vars {
                let mut g = p.grad();
                if g.defined() {
                    let _ = g.zero_();
                }
            }
            norm
        })
    }
}

/// The EMA decay after optimiser step `step` (ema_pytorch 0.2.2 with the official settings): 0 up to the
/// warm-up, then `min(beta, 1 − (step − after)^(−2/3))`.
pub fn ema_decay(step: u64, after: u64, beta: f64) -> f64 {
    let epoch = step.saturating_sub(after + 1) as f64;
    if epoch <= 0.0 {
        return 0.0;
    }
    (1.0 - (1.0 + epoch).powf(-2.0 / 3.0)).clamp(0.0, beta)
}

/// Updates the EMA copy after optimiser step `step`: every `every` steps, a copy up to the warm-up
/// (`after` steps), a moving average with [`ema_decay`] after it.
pub fn ema_update(ema: &[(String, Tensor)], online: &[(String, Tensor)], step: u64, every: u64, after: u64, beta: f64) {
    if step % every != 0 {
        return;
    }
    tch::no_grad(|| {
        let decay = if step <= after { 0.0 } else { ema_decay(step, after, beta) };
        for ((_, e), (_, o)) in ema.iter().zip(online) {
            let _ = e.shallow_clone().g_mul_scalar_(decay).g_add_(&(o * (1.0 - decay)));
        }
    })
}
