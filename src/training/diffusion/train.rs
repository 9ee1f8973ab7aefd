//! Training of the denoiser (reference §5.3): x0 objective, SNR-weighted L1 (official) or min-SNR, Adam
//! with gradient-norm clipping and accumulation, horizontal flips, EMA, checkpoints with resume.
//!
//! Adam and the EMA ([`crate::training::optim`]) are written out (a few tensor ops) so that their state goes into
//! the checkpoint: a resumed run continues exactly where the interrupted one stopped. Every random draw
//! of step `s` comes from the seed and `s` alone (batch, crops, flips from [`Rng`], time steps and noise from libtorch's generator
//! reseeded per step), so a resumed run equals an uninterrupted one.

use super::data::FrameSet;
use crate::training::optim::{ema_update, Adam};
use crate::diffusion::checkpoint::{self, sorted_variables, DiffusionMeta, EMA, ONLINE};
use crate::diffusion::schedule::Schedule;
use crate::correction::{CorrectionConfig, Corrector};
use crate::error::{Error, Result};
use crate::geometry::PivotPoseSampler;
use crate::inpainting::Start;
use crate::nn::denoiser::{Denoiser, DenoiserConfig};
use crate::nn::unet::{parameter_count, Preset};
use crate::rng::Rng;
use rayon::prelude::*;
use serde::Serialize;
use std::path::PathBuf;
use tch::{nn, Device, Kind, Tensor};

/// The checkpoint written every `checkpoint_every` steps and at the end.
pub const LATEST: &str = "latest.safetensors";
/// The loss log (JSON lines, one per logged step).
pub const LOSS_LOG: &str = "loss.jsonl";

/// Loss weight per time step.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Weighting {
    /// `SNR_t`, unclipped (official, lucidrains' x0 objective).
    Snr,
    /// `min(SNR_t, 5)` (Hang et al. 2023): less weight on the nearly clean steps.
    MinSnr,
}

/// Everything a training run needs besides the data.
#[derive(Clone, Debug, Serialize)]
pub struct DiffusionTrainOptions {
    pub preset: Preset,
    /// Optimiser steps in total (a resumed run continues up to this count).
    pub steps: u64,
    /// Frames per forward pass.
    pub batch: usize,
    /// Forward passes per optimiser step (official 2).
    pub grad_accum: usize,
    /// Adam learning rate (official 8e-5) and betas (0.9, 0.99).
    pub lr: f64,
    pub betas: (f64, f64),
    /// Gradient-norm clip (official 1).
    pub clip: f64,
    pub weighting: Weighting,
    /// Train only on time steps below this (None: all T). For a model that only ever samples from a
    /// start step below it (`start = "push_pull"`): its whole capacity goes to the nearly clean steps.
    pub max_t: Option<usize>,
    /// Hole-aware training (see [`super::holes`]): each frame gets the holes of a camera round trip,
    /// filled by push–pull, and is noised from that fill instead of from the clean frame; the loss counts
    /// only pixels with true depth, holes `hole_weight` times as much as the rest. For a model sampled
    /// from `start = "push_pull"` at a small start step (with `max_t`).
    pub holes: bool,
    pub hole_weight: f64,
    /// The classical fill of the holes, as the sampler's `start` will fill them (push–pull or background;
    /// `noise` is not a fill and is refused).
    pub hole_start: Start,
    /// The corrections a holed frame goes through, one drawn per frame (as the build's
    /// `[correct.condition]` drops pixels from a re-projected view before the fill).
    pub hole_corrections: Vec<CorrectionConfig>,
    /// EMA decay cap, update interval and warm-up (official 0.995, 10, 100).
    pub ema_beta: f64,
    pub ema_every: u64,
    pub ema_after: u64,
    /// Random `crop`×`crop` windows (intrinsics shifted to match); None: whole frames (official).
    pub crop: Option<usize>,
    /// Random horizontal flips (official: on; here cx follows the flip, `cx' = W − 1 − cx`).
    pub hflip: bool,
    pub seed: u64,
    pub checkpoint_every: u64,
    /// Write `preview-<step>.png` (unconditional samples of the EMA network) at every checkpoint.
    pub previews: bool,
    pub out: PathBuf,
    pub resume: bool,
    /// Start from this checkpoint's sampling weights (EMA when present) instead of a random
    /// initialisation: a fine-tuning run (fresh Adam and EMA warm-up, step 0). `resume` wins when
    /// `out` already holds a checkpoint.
    pub init: Option<PathBuf>,
    #[serde(skip)]
    pub device: Device,
    pub progress: bool,
}

impl DiffusionTrainOptions {
    /// The defaults of a preset: the paper preset is the official recipe; the tiny one trains on a CPU in
    /// minutes (lr 1e-3, batch 8, no accumulation, 64² crops, min-SNR weighting).
    pub fn for_preset(preset: Preset, out: PathBuf) -> Self {
        let tiny = preset == Preset::Tiny;
        DiffusionTrainOptions {
            preset,
            steps: if tiny { 3000 } else { 2_000_000 },
            batch: if tiny { 8 } else { 32 },
            grad_accum: if tiny { 1 } else { 2 },
            lr: if tiny { 1e-3 } else { 8e-5 },
            betas: (0.9, 0.99),
            clip: 1.0,
            weighting: if tiny { Weighting::MinSnr } else { Weighting::Snr },
            max_t: None,
            holes: false,
            hole_weight: 4.0,
            hole_start: Start::PushPull,
            hole_corrections: vec![CorrectionConfig::None {}, CorrectionConfig::OFFICIAL_MIN_POOL],
            ema_beta: 0.995,
            ema_every: 10,
            ema_after: 100,
            crop: tiny.then_some(64),
            hflip: true,
            seed: 0,
            checkpoint_every: if tiny { 250 } else { 1000 },
            previews: true,
            out,
            resume: false,
            init: None,
            device: Device::Cpu,
            progress: false,
        }
    }

    fn validate(&self, data: &FrameSet) -> Result<()> {
        let bad = |k: &str, m: String| Err(Error::config(k, m));
        if self.steps == 0 || self.batch == 0 || self.grad_accum == 0 || self.checkpoint_every == 0 || self.ema_every == 0 {
            return bad("--steps/--batch/--grad-accum", "must be at least 1".into());
        }
        if !(self.lr > 0.0 && self.lr < 1.0) || !(self.clip > 0.0) || !(self.ema_beta > 0.0 && self.ema_beta < 1.0) {
            return bad("--lr", format!("lr {} / clip {} / ema {} out of range", self.lr, self.clip, self.ema_beta));
        }
        let m = self.preset.diffusion_unet().size_multiple() as usize;
        let (w, h) = (data.width, data.height);
        let (cw, ch) = self.crop.map_or((w, h), |c| (c, c));
        if cw == 0 || cw % m != 0 || ch % m != 0 || cw > w || ch > h {
            return bad("--crop", format!("must be a multiple of {m} no larger than the frames ({w}x{h})"));
        }
        if self.max_t.is_some_and(|t| t == 0 || t > Schedule::official().len()) {
            return bad("--max-t", format!("must be in 1..={}", Schedule::official().len()));
        }
        if !(self.hole_weight > 0.0 && self.hole_weight.is_finite()) {
            return bad("--hole-weight", format!("must be positive, got {}", self.hole_weight));
        }
        if self.holes {
            if self.hole_corrections.is_empty() {
                return bad("--holes-correction", "hole-aware training needs at least one correction".into());
            }
            if self.hole_start == Start::Noise {
                return bad("--holes-start", "must be a classical fill (push-pull or background), the start a holed frame is noised from".into());
            }
            for c in &self.hole_corrections {
                c.validate("--holes-correction")?;
            }
        }
        Ok(())
    }
}

/// Size and intrinsics of preview samples: the training crop (centred in the first frame) or the frame.
fn preview_view(data: &FrameSet, opts: &DiffusionTrainOptions) -> (usize, [f64; 4]) {
    let size = opts.crop.unwrap_or(data.width.min(data.height));
    let [fx, fy, cx, cy] = data.frames[0].intrinsics;
    let (left, top) = ((data.width - size) / 2, (data.height - size) / 2);
    (size, [fx, fy, cx - left as f64, cy - top as f64])
}

/// One batch: clean frames `[B, 1, S, S]` and intrinsics `[B, 4]`; with `opts.holes`, also the holed
/// starts and per-pixel loss weights, both `[B, 1, S, S]`.
fn make_batch(data: &FrameSet, opts: &DiffusionTrainOptions, correctors: &[Box<dyn Corrector>], rng: &mut Rng) -> (Tensor, Tensor, Option<Holes>) {
    let (w, h) = (data.width, data.height);
    let (cw, ch) = opts.crop.map_or((w, h), |c| (c, c));
    let b = opts.batch;
    let mut x = vec![0f32; b * cw * ch];
    let mut k = vec![0f32; b * 4];
    let (mut start, mut weight) = (Vec::new(), Vec::new());
    // Draws in a fixed order (frame, crop, flip, then for holes the motion and the correction); the holed
    // frames are then made in parallel, off this thread, so a correction U-Net's one-thread setting does
    // not reach the training's libtorch thread.
    let draws: Vec<_> = (0..b)
        .map(|_| {
            let f = &data.frames[rng.below(data.len() as u64) as usize];
            let (x0, y0) = (rng.below((w - cw + 1) as u64) as usize, rng.below((h - ch + 1) as u64) as usize);
            let flip = opts.hflip && rng.uniform() < 0.5;
            let holes = opts.holes.then(|| {
                let motion = super::holes::sample_motion(&PivotPoseSampler::default(), rng);
                (motion, rng.below(correctors.len() as u64) as usize)
            });
            (f, x0, y0, flip, holes)
        })
        .collect();
    let fill = opts.hole_start.classical_fill();
    let holed: Vec<_> = draws
        .par_iter()
        .map(|(f, _, _, _, holes)| {
            holes.map(|(motion, c)| super::holes::holed_frame(&f.depth, w, h, f.intrinsics, &motion, correctors[c].as_ref(), fill))
        })
        .collect();
    for (i, ((f, x0, y0, flip, _), holed)) in draws.into_iter().zip(holed).enumerate() {
        for r in 0..ch {
            for c in 0..cw {
                let sc = if flip { x0 + cw - 1 - c } else { x0 + c };
                let (src, dst) = ((y0 + r) * w + sc, i * cw * ch + r * cw + c);
                x[dst] = f.depth[src];
                if let Some(holed) = &holed {
                    start.push(holed.start[src]);
                    let truth = f.depth[src] > -1.0;
                    weight.push(if !truth { 0.0 } else if holed.holes[src] { opts.hole_weight as f32 } else { 1.0 });
                }
            }
        }
        let [fx, fy, cx, cy] = f.intrinsics;
        // Cropping shifts the principal point; a flip mirrors it about the crop's centre column.
        let cx = cx - x0 as f64;
        let cx = if flip { (cw - 1) as f64 - cx } else { cx };
        k[i * 4..i * 4 + 4].copy_from_slice(&[fx as f32, fy as f32, cx as f32, (cy - y0 as f64) as f32]);
    }
    let image = |v: &[f32]| Tensor::from_slice(v).view([b as i64, 1, ch as i64, cw as i64]).to_device(opts.device);
    let holes = opts.holes.then(|| Holes { start: image(&start), weight: image(&weight) });
    let k = Tensor::from_slice(&k).view([b as i64, 4]).to_device(opts.device);
    (image(&x), k, holes)
}

/// The hole-aware part of a batch (`DiffusionTrainOptions::holes`).
pub struct Holes {
    /// What is noised instead of the clean frame: known depths with the classical fill in the holes.
    pub start: Tensor,
    /// Per-pixel loss weight: 0 without true depth, `hole_weight` in holes, 1 elsewhere.
    pub weight: Tensor,
}

/// The loss of one batch: the mean over the batch of the time-step weight times the per-frame mean
/// |x̂0 − x0| (with `holes`: x_t noised from the holed start, and the pixel-weighted mean).
pub fn batch_loss(net: &Denoiser, schedule: &Schedule, weighting: Weighting, x0: &Tensor, k: &Tensor, t: &[i64], holes: Option<&Holes>) -> Tensor {
    let device = x0.device();
    let b = t.len() as i64;
    let ab: Vec<f32> = t.iter().map(|&t| schedule.alpha_bar(t) as f32).collect();
    let w: Vec<f32> = t
        .iter()
        .map(|&t| {
            let snr = schedule.snr(t as usize);
            (match weighting {
                Weighting::Snr => snr,
                Weighting::MinSnr => snr.min(5.0),
            }) as f32
        })
        .collect();
    let ab = Tensor::from_slice(&ab).view([b, 1, 1, 1]).to_device(device);
    let noise = x0.randn_like();
    let noised_from = holes.map_or(x0, |h| &h.start);
    let xt = noised_from * ab.sqrt() + noise * (ab.ones_like() - &ab).sqrt();
    let pred = net.forward(&xt, &Tensor::from_slice(t).to_device(device), k);
    let dims = &[1i64, 2, 3][..];
    let per_frame = match holes {
        None => (pred - x0).abs().mean_dim(dims, false, Kind::Float),
        Some(h) => ((pred - x0).abs() * &h.weight).sum_dim_intlist(dims, false, Kind::Float)
            / h.weight.sum_dim_intlist(dims, false, Kind::Float).clamp_min(1.0),
    };
    (per_frame * Tensor::from_slice(&w).to_device(device)).mean(Kind::Float)
}

/// One logged step.
#[derive(Clone, Debug, Serialize)]
pub struct StepReport {
    pub step: u64,
    /// Mean loss over the steps since the last report.
    pub loss: f64,
    pub grad_norm: f64,
    pub seconds: f64,
}

/// What a run did.
#[derive(Clone, Debug)]
pub struct DiffusionTrainReport {
    pub first_step: u64,
    pub parameters: i64,
    pub final_loss: f64,
}

/// Trains a denoiser on `data`; writes `opts.out/`[`LATEST`] (model, EMA, Adam moments) every
/// `checkpoint_every` steps and at the end, and [`LOSS_LOG`]. `on_report` sees every logged step.
pub fn train_diffusion(data: &FrameSet, opts: &DiffusionTrainOptions, mut on_report: impl FnMut(&StepReport)) -> Result<DiffusionTrainReport> {
    opts.validate(data)?;
    std::fs::create_dir_all(&opts.out).map_err(|e| Error::io(&opts.out, e))?;
    let schedule = Schedule::official();
    tch::manual_seed(opts.seed as i64);
    let config = DenoiserConfig::from_preset(opts.preset);
    let vs = nn::VarStore::new(opts.device);
    let net = Denoiser::new(&vs.root(), &config)?;
    let ema_vs = nn::VarStore::new(opts.device);
    let ema_net = Denoiser::new(&ema_vs.root(), &config)?;
    let (online, ema) = (sorted_variables(&vs), sorted_variables(&ema_vs));
    tch::no_grad(|| {
        for ((_, e), (_, o)) in ema.iter().zip(&online) {
            e.shallow_clone().copy_(o);
        }
    });
    let mut adam = Adam::new(&online, opts.lr, opts.betas);
    let correctors: Vec<Box<dyn Corrector>> = if opts.holes { opts.hole_corrections.iter().map(|c| c.build()).collect() } else { Vec::new() };
    let latest = opts.out.join(LATEST);
    let mut start = 0u64;
    if opts.resume && latest.exists() {
        let meta = checkpoint::read_meta(&latest)?;
        if meta.net != config {
            return Err(Error::config("--resume", format!("{} holds another network ({:?})", latest.display(), meta.net.preset)));
        }
        let tensors = checkpoint::read_tensors(&latest)?;
        for (prefix, vars, what) in [(ONLINE, &online, "online"), (EMA, &ema, "EMA"), ("opt.m.", &adam.m, "Adam m"), ("opt.v.", &adam.v, "Adam v")] {
            checkpoint::copy_into(&latest, &checkpoint::group(&tensors, prefix), vars, what)?;
        }
        start = meta.step;
    } else if let Some(init) = &opts.init {
        let (meta, weights) = checkpoint::read_sampling_weights(init)?;
        if meta.net != config {
            return Err(Error::config("--init", format!("{} holds another network ({:?})", init.display(), meta.net.preset)));
        }
        checkpoint::copy_into(init, &weights, &online, "initial")?;
        checkpoint::copy_into(init, &weights, &ema, "initial")?;
    }
    let save = |step: u64, loss: f64, adam: &Adam| {
        let meta = DiffusionMeta {
            format: checkpoint::FORMAT.into(),
            net: config.clone(),
            step,
            info: serde_json::json!({"options": opts, "frames": data.len(), "last_loss": loss}),
        };
        checkpoint::save(&latest, &meta, &online, &ema, &[("opt.m.", &adam.m), ("opt.v.", &adam.v)])
    };
    let log_path = opts.out.join(LOSS_LOG);
    let mut log = std::fs::OpenOptions::new().create(true).append(true).open(&log_path).map_err(|e| Error::io(&log_path, e))?;
    let bar = crate::runtime::progress::bar(opts.steps, opts.progress, "step");
    bar.set_position(start);
    let t0 = std::time::Instant::now();
    let (mut sum, mut count, mut last_loss) = (0f64, 0u64, f64::NAN);
    let t_end = opts.max_t.unwrap_or(schedule.len()) as u64;
    for step in start + 1..=opts.steps {
        let mut rng = Rng::new(opts.seed).fork(step);
        tch::manual_seed((opts.seed ^ step.wrapping_mul(0x9E37_79B9_7F4A_7C15)) as i64);
        let mut step_loss = 0.0;
        for _ in 0..opts.grad_accum {
            let (x0, k, holes) = make_batch(data, opts, &correctors, &mut rng);
            let t: Vec<i64> = (0..opts.batch).map(|_| rng.below(t_end) as i64).collect();
            let loss = batch_loss(&net, &schedule, opts.weighting, &x0, &k, &t, holes.as_ref()) / opts.grad_accum as f64;
            loss.backward();
            step_loss += loss.double_value(&[]);
        }
        if !step_loss.is_finite() {
            return Err(Error::Internal(format!("training loss became {step_loss} at step {step}")));
        }
        let grad_norm = adam.step(&online, step, opts.clip);
        ema_update(&ema, &online, step, opts.ema_every, opts.ema_after, opts.ema_beta);
        sum += step_loss;
        count += 1;
        last_loss = step_loss;
        bar.set_message(format!("loss {:.4}", sum / count as f64));
        bar.inc(1);
        if step % opts.checkpoint_every == 0 || step == opts.steps {
            let report = StepReport { step, loss: sum / count as f64, grad_norm, seconds: t0.elapsed().as_secs_f64() };
            use std::io::Write;
            writeln!(log, "{}", serde_json::to_string(&report).expect("json")).map_err(|e| Error::io(&log_path, e))?;
            save(step, report.loss, &adam)?;
            if opts.previews {
                let (size, k) = preview_view(data, opts);
                let path = opts.out.join(format!("preview-{step:07}.png"));
                tch::no_grad(|| super::preview::write_preview(&ema_net, &schedule, size, k, opts.seed, &path, opts.device))?;
            }
            on_report(&report);
            (sum, count) = (0.0, 0);
        }
    }
    bar.finish_and_clear();
    Ok(DiffusionTrainReport { first_step: start + 1, parameters: parameter_count(&vs), final_loss: last_loss })
}
