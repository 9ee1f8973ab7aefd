//! DDIM sampling with the range–null-space (DDNM) consistency step (reference §5.4).
//!
//! Per step `(t, t_next)`: `x0 = clamp(net(x_t, t, K), −1, 1)`; `ε = (x_t/√ᾱ_t − x0)/√(1/ᾱ_t − 1)` from the
//! clamped, un-replaced x0; `x̂0 = M⊙y + (1 − M)⊙x0`; then `x_next = √ᾱ_next·x̂0 + c·ε + σ·z` with
//! `σ = η·√((1 − ᾱ_t/ᾱ_next)(1 − ᾱ_next)/(1 − ᾱ_t))`, `c = √(1 − ᾱ_next − σ²)`. The result is the last x̂0,
//! so every known pixel equals y bit for bit. All noise (the start image and every z) comes from each
//! problem's own seeded [`Rng`], so a problem's output does not depend on the other problems of its batch
//! or on libtorch's generator.
//!
//! Optionally (not the official sampler) the chain starts at an intermediate step `s` from a noised
//! initial estimate, `x_s = √ᾱ_s·x_init + √(1 − ᾱ_s)·z` (SDEdit-style), where `x_init` is the known pixels
//! and a classical fill elsewhere: the coarse depth then comes from the known neighbourhood and the
//! model adds what it learned at the finer noise levels.
//!
//! Also optional: RePaint-style resampling ([`Resample`]), which runs each block of steps several times,
//! re-noising the state back to the block's first step in between.

use super::schedule::Schedule;
use super::model::X0Model;
use crate::rng::Rng;
use serde::{Deserialize, Serialize};
use tch::{Device, Kind, Tensor};

/// Sampler settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SamplerOptions {
    /// DDIM steps (paper 250 of T = 1000).
    pub steps: usize,
    /// DDIM η (official 1.0: fully stochastic).
    pub eta: f64,
    /// Start at this step from each problem's noised `init` instead of pure noise at T − 1 (None:
    /// official).
    pub start_step: Option<usize>,
    /// RePaint-style resampling (None: official).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resample: Option<Resample>,
}

impl SamplerOptions {
    /// The official sampler: 250 steps, η = 1, from pure noise.
    pub const OFFICIAL: SamplerOptions = SamplerOptions { steps: 250, eta: 1.0, start_step: None, resample: None };
}

/// RePaint-style resampling (Lugmayr et al. 2022; not in the official sampler): the DDIM chain runs in
/// blocks of `jump` steps, and after a block the state is re-noised back to the block's first step and
/// the block runs again, `repeats` times in all. The known pixels are imposed at every step, so the
/// filled region gets several passes to agree with them. The last step (to −1) is never repeated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Resample {
    pub jump: usize,
    pub repeats: usize,
}

/// One move of the sampling chain.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Move {
    /// A DDIM step from `t` down to `t_next` (−1: the end of the chain).
    Down(i64, i64),
    /// Forward diffusion of the state from step `from` up to step `to`:
    /// `x_to = √(ᾱ_to/ᾱ_from)·x_from + √(1 − ᾱ_to/ᾱ_from)·z`.
    Up(i64, i64),
}

/// The moves of a chain over DDIM `pairs` (ending at −1), with `resample` blocks when given.
pub fn chain(pairs: &[(i64, i64)], resample: Option<Resample>) -> Vec<Move> {
    let down = |&(t, n): &(i64, i64)| Move::Down(t, n);
    let Some(r) = resample.filter(|r| r.jump > 0 && r.repeats > 1) else {
        return pairs.iter().map(down).collect();
    };
    let (body, last) = pairs.split_at(pairs.len().saturating_sub(1));
    let mut moves = Vec::new();
    for block in body.chunks(r.jump) {
        for rep in 0..r.repeats {
            if rep > 0 {
                moves.push(Move::Up(block[block.len() - 1].1, block[0].0));
            }
            moves.extend(block.iter().map(down));
        }
    }
    moves.extend(last.iter().map(down));
    moves
}

/// One inpainting problem at the network's resolution.
pub struct Problem<'a> {
    /// Known values in network space ([−1, 1]); unknown pixels are ignored.
    pub y: &'a [f32],
    /// Known-pixel mask M (same length as `y`).
    pub known: &'a [bool],
    /// Working-resolution intrinsics `[fx, fy, cx, cy]`, pixels.
    pub intrinsics: [f64; 4],
    /// Seed of every random draw of this problem.
    pub seed: u64,
    /// Initial estimate of the whole map in network space (required with `start_step`).
    pub init: Option<&'a [f32]>,
}

/// Samples every problem (all of size `width`×`height`) in one batch and returns x̂0 per problem in
/// network space. H and W are padded with unknown pixels up to the U-Net's size multiple.
pub fn ddnm_sample(
    net: &dyn X0Model,
    schedule: &Schedule,
    opts: &SamplerOptions,
    width: usize,
    height: usize,
    problems: &[Problem<'_>],
    device: Device,
) -> Vec<Vec<f32>> {
    if problems.is_empty() {
        return Vec::new();
    }
    let m = net.size_multiple();
    let (pw, ph) = (width.div_ceil(m) * m, height.div_ceil(m) * m);
    let (b, n) = (problems.len(), pw * ph);
    let shape = [b as i64, 1, ph as i64, pw as i64];
    let mut y = vec![-1f32; b * n];
    let mut init = vec![-1f32; b * n];
    let mut known = vec![false; b * n];
    for (i, p) in problems.iter().enumerate() {
        assert!(p.y.len() == width * height && p.known.len() == width * height, "problem size");
        let start = p.init.unwrap_or(p.y);
        assert!(start.len() == width * height, "init size");
        assert!(opts.start_step.is_none() || p.init.is_some(), "a start step needs an initial estimate");
        for r in 0..height {
            let (dst, src) = (i * n + r * pw, r * width);
            y[dst..dst + width].copy_from_slice(&p.y[src..src + width]);
            init[dst..dst + width].copy_from_slice(&start[src..src + width]);
            known[dst..dst + width].copy_from_slice(&p.known[src..src + width]);
        }
    }
    let k: Vec<f32> = problems.iter().flat_map(|p| p.intrinsics.map(|v| v as f32)).collect();
    let mut rngs: Vec<Rng> = problems.iter().map(|p| Rng::new(p.seed)).collect();
    let noise = |rngs: &mut [Rng]| {
        let mut buf = vec![0f32; b * n];
        for (rng, chunk) in rngs.iter_mut().zip(buf.chunks_mut(n)) {
            rng.fill_normal_f32(chunk);
        }
        Tensor::from_slice(&buf).view(shape).to_device(device)
    };
    let out = tch::no_grad(|| {
        let y = Tensor::from_slice(&y).view(shape).to_device(device);
        let known = Tensor::from_slice(&known).view(shape).to_device(device);
        let k = Tensor::from_slice(&k).view([b as i64, 4]).to_device(device);
        let pairs = match opts.start_step {
            None => schedule.ddim_pairs(opts.steps),
            Some(s) => schedule.ddim_pairs_from(s, opts.steps),
        };
        let mut x = match opts.start_step {
            None => noise(&mut rngs),
            Some(s) => {
                let ab = schedule.alpha_bar(pairs[0].0.min(s as i64));
                let init = Tensor::from_slice(&init).view(shape).to_device(device);
                let known_init = y.where_self(&known, &init);
                known_init * ab.sqrt() + noise(&mut rngs) * (1.0 - ab).sqrt()
            }
        };
        let mut x0 = y.shallow_clone();
        for mv in chain(&pairs, opts.resample) {
            let (t, t_next) = match mv {
                Move::Down(t, t_next) => (t, t_next),
                Move::Up(from, to) => {
                    let ratio = schedule.alpha_bar(to) / schedule.alpha_bar(from);
                    x = x * ratio.sqrt() + noise(&mut rngs) * (1.0 - ratio).sqrt();
                    continue;
                }
            };
            let time = Tensor::full([b as i64], t, (Kind::Int64, device));
            let pred = net.predict_x0(&x, &time, &k).clamp(-1.0, 1.0);
            let ab = schedule.alpha_bar(t);
            let eps = (&x * (1.0 / ab).sqrt() - &pred) / (1.0 / ab - 1.0).sqrt();
            x0 = y.where_self(&known, &pred);
            if t_next < 0 {
                break;
            }
            let ab_next = schedule.alpha_bar(t_next);
            let sigma = opts.eta * ((1.0 - ab / ab_next) * (1.0 - ab_next) / (1.0 - ab)).sqrt();
            let c = (1.0 - ab_next - sigma * sigma).max(0.0).sqrt();
            x = &x0 * ab_next.sqrt() + eps * c;
            if sigma > 0.0 {
                x += noise(&mut rngs) * sigma;
            }
        }
        x0.to_device(Device::Cpu).to_kind(Kind::Float).contiguous()
    });
    let flat: Vec<f32> = Vec::try_from(out.flatten(0, -1)).expect("float output");
    (0..b)
        .map(|i| {
            let mut v = Vec::with_capacity(width * height);
            for r in 0..height {
                v.extend_from_slice(&flat[i * n + r * pw..i * n + r * pw + width]);
            }
            v
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resampling_repeats_each_block_after_renoising_it_and_never_the_last_step() {
        let pairs = [(20, 15), (15, 10), (10, 5), (5, -1)];
        let plain: Vec<Move> = pairs.iter().map(|&(t, n)| Move::Down(t, n)).collect();
        assert_eq!(chain(&pairs, None), plain);
        assert_eq!(chain(&pairs, Some(Resample { jump: 2, repeats: 1 })), plain);
        use Move::{Down, Up};
        assert_eq!(
            chain(&pairs, Some(Resample { jump: 2, repeats: 2 })),
            vec![Down(20, 15), Down(15, 10), Up(10, 20), Down(20, 15), Down(15, 10), Down(10, 5), Up(5, 10), Down(10, 5), Down(5, -1)]
        );
        let three = chain(&pairs, Some(Resample { jump: 3, repeats: 3 }));
        assert_eq!(three.iter().filter(|m| matches!(m, Up(..))).count(), 2);
        assert_eq!(three.len(), 3 * 3 + 2 + 1);
        assert_eq!(three.last(), Some(&Down(5, -1)));
    }
}
