//! The correction network's training loop (reference §4.2): BCE on the keep label, Adam, exponential LR
//! decay per epoch, gradient-norm clipping, validation and checkpoints every epoch, resume.

use crate::nn::checkpoint::{load_weights, read_meta, save_correction, CheckpointMeta};
use crate::nn::correction::{CorrectionNet, CorrectionNetConfig};
use super::data::LabelSet;
use super::evaluate::{evaluate_net, THRESHOLDS};
use super::metrics::MaskMetrics;
use crate::nn::unet::Preset;
use crate::error::{Error, Result};
use crate::rng::Rng;
use serde::Serialize;
use std::io::Write;
use std::path::PathBuf;
use tch::{nn, nn::OptimizerConfig, Device, Kind, Reduction, Tensor};

/// The checkpoint written after every epoch.
pub const LATEST: &str = "latest.safetensors";
/// The checkpoint with the best validation mIoU at τ_m 0.99.
pub const BEST: &str = "best.safetensors";
/// The per-epoch log (JSON lines).
pub const METRICS_LOG: &str = "metrics.jsonl";
/// The metric `best.safetensors` is chosen by.
pub const BEST_METRIC: &str = "val_miou_at_0.99";

/// Which pixels the loss averages over.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum LossPixels {
    /// Every pixel (official): holes of `I_s` where `I_d` has depth are labelled "drop" too.
    All,
    /// Only pixels with input depth: the pixels a corrector can keep or drop.
    Depth,
}

/// Everything a training run needs besides the data.
#[derive(Clone, Debug, Serialize)]
pub struct TrainOptions {
    pub preset: Preset,
    /// DepthAugment's three channels (official: on).
    pub augment: bool,
    /// Total epochs (a resumed run continues up to this count).
    pub epochs: u32,
    pub batch: usize,
    /// Initial learning rate (official 4e-5).
    pub lr: f64,
    /// ExponentialLR factor per epoch (official 0.95).
    pub lr_gamma: f64,
    /// Adam betas (official 0.9, 0.99).
    pub betas: (f64, f64),
    /// Gradient-norm clip (official 1.0).
    pub clip: f64,
    pub seed: u64,
    /// Train on random `crop`×`crop` windows of the maps (None: whole maps, official); the network is
    /// fully convolutional, so validation and inference use whole maps.
    pub crop: Option<usize>,
    /// Random horizontal flips of training examples (official: none).
    pub hflip: bool,
    pub loss_pixels: LossPixels,
    /// Loss weight of the pixels labelled "drop" (official 1). Drops are rare (~7 % of the pixels with
    /// depth), and a weight w moves the keep probability 0.5 to where an unweighted network says
    /// w / (1 + w), which is where mIoU at τ_m 0.5 peaks when w ≈ 2.5.
    pub drop_weight: f64,
    pub out: PathBuf,
    pub resume: bool,
    #[serde(skip)]
    pub device: Device,
    pub progress: bool,
}

impl TrainOptions {
    /// The defaults of a preset: official optimiser settings; the tiny preset uses a larger learning rate
    /// (2e-3), 128² crops and the depth-pixel loss so it trains on a CPU in minutes.
    pub fn for_preset(preset: Preset, out: PathBuf) -> Self {
        let tiny = preset == Preset::Tiny;
        TrainOptions {
            preset,
            augment: true,
            epochs: if tiny { 16 } else { 100 },
            batch: if tiny { 8 } else { 4 },
            lr: if tiny { 2e-3 } else { 4e-5 },
            lr_gamma: 0.95,
            betas: (0.9, 0.99),
            clip: 1.0,
            seed: 0,
            crop: tiny.then_some(128),
            hflip: false,
            loss_pixels: if tiny { LossPixels::Depth } else { LossPixels::All },
            drop_weight: 1.0,
            out,
            resume: false,
            device: Device::Cpu,
            progress: false,
        }
    }

    fn validate(&self, train: &LabelSet) -> Result<()> {
        let bad = |k: &str, m: String| Err(Error::config(k, m));
        if self.epochs == 0 || self.batch == 0 {
            return bad("--epochs/--batch", "must be at least 1".into());
        }
        if !(self.lr > 0.0 && self.lr < 1.0) || !(self.lr_gamma > 0.0 && self.lr_gamma <= 1.0) || !(self.clip > 0.0) {
            return bad("--lr", format!("lr {} / gamma {} / clip {} out of range", self.lr, self.lr_gamma, self.clip));
        }
        if !(self.drop_weight > 0.0 && self.drop_weight.is_finite()) {
            return bad("--drop-weight", format!("must be positive, got {}", self.drop_weight));
        }
        if train.is_empty() {
            return bad("--labels", "the training label set has no `ok` rows".into());
        }
        if let Some(c) = self.crop {
            let m = self.preset.correction_unet(self.augment).size_multiple() as usize;
            if c == 0 || c % m != 0 || c > train.width || c > train.height {
                return bad(
                    "--crop",
                    format!("must be a multiple of {m} no larger than the maps ({}x{})", train.width, train.height),
                );
            }
        }
        Ok(())
    }
}

/// What one epoch did.
#[derive(Clone, Debug, Serialize)]
pub struct EpochReport {
    /// 1-based epoch number.
    pub epoch: u32,
    pub lr: f64,
    /// Mean training loss of the epoch.
    pub train_loss: f64,
    /// Validation at τ_m 0.5 and 0.99.
    pub val_05: MaskMetrics,
    pub val_099: MaskMetrics,
    /// Seconds of the training steps, and of the whole epoch with validation and checkpoints.
    pub train_seconds: f64,
    pub seconds: f64,
    /// Whether this epoch is the new best.
    pub best: bool,
}

/// What a run did.
#[derive(Clone, Debug)]
pub struct TrainReport {
    pub epochs: Vec<EpochReport>,
    /// The first epoch trained by this call (1-based; > 1 after a resume).
    pub first_epoch: u32,
    pub parameters: i64,
    pub best_metric: Option<f64>,
}

/// One batch as tensors: inputs, labels and loss weights `[B, 1, S, S]`.
fn make_batch(set: &LabelSet, idx: &[usize], opts: &TrainOptions, rng: &mut Rng) -> (Tensor, Tensor, Tensor) {
    let (w, h) = (set.width, set.height);
    let (cw, ch) = opts.crop.map_or((w, h), |c| (c, c));
    let n = idx.len();
    let (mut x, mut y, mut m) = (vec![0f32; n * cw * ch], vec![0f32; n * cw * ch], vec![0f32; n * cw * ch]);
    for (b, &i) in idx.iter().enumerate() {
        let e = &set.examples[i];
        let input = e.input();
        let (x0, y0) = (rng.below((w - cw + 1) as u64) as usize, rng.below((h - ch + 1) as u64) as usize);
        let flip = opts.hflip && rng.uniform() < 0.5;
        for r in 0..ch {
            for c in 0..cw {
                let sc = if flip { x0 + cw - 1 - c } else { x0 + c };
                let s = (y0 + r) * w + sc;
                let d = b * cw * ch + r * cw + c;
                x[d] = input[s];
                y[d] = e.keep[s] as u8 as f32;
                let counted = match opts.loss_pixels {
                    LossPixels::All => true,
                    LossPixels::Depth => input[s] > 0.0,
                };
                m[d] = if !counted { 0.0 } else if e.keep[s] { 1.0 } else { opts.drop_weight as f32 };
            }
        }
    }
    let t = |v: Vec<f32>| Tensor::from_slice(&v).view([n as i64, 1, ch as i64, cw as i64]).to_device(opts.device);
    (t(x), t(y), t(m))
}

/// Trains a correction network on `train`, validating on `val` after every epoch; writes
/// [`LATEST`], [`BEST`] and [`METRICS_LOG`] into `opts.out`. `on_epoch` sees each epoch's report.
pub fn train_correction(
    train: &LabelSet,
    val: &LabelSet,
    opts: &TrainOptions,
    mut on_epoch: impl FnMut(&EpochReport),
) -> Result<TrainReport> {
    opts.validate(train)?;
    if val.is_empty() {
        return Err(Error::config(
            "--val-labels",
            "the validation set is empty (give --val-labels or more than one fused window)",
        ));
    }
    if (val.width, val.height) != (train.width, train.height) {
        return Err(Error::config(
            "--val-labels",
            format!("validation maps are {}x{}, training maps {}x{}", val.width, val.height, train.width, train.height),
        ));
    }
    std::fs::create_dir_all(&opts.out).map_err(|e| Error::io(&opts.out, e))?;
    tch::manual_seed(opts.seed as i64);
    let config = CorrectionNetConfig::from_preset(opts.preset, opts.augment);
    let mut vs = nn::VarStore::new(opts.device);
    let net = CorrectionNet::new(&vs.root(), &config)?;
    let parameters = crate::nn::unet::parameter_count(&vs);

    let (mut start, mut lr, mut best) = (0u32, opts.lr, None::<f64>);
    let latest = opts.out.join(LATEST);
    if opts.resume && latest.exists() {
        let meta = read_meta(&latest)?;
        if meta.net != config {
            return Err(Error::config(
                "--resume",
                format!(
                    "{} holds another network ({:?}, augment {})",
                    latest.display(),
                    meta.net.preset,
                    meta.net.augment
                ),
            ));
        }
        load_weights(&latest, &mut vs)?;
        (start, lr, best) = (meta.epoch, meta.next_lr, meta.best_metric);
    }
    let adam = nn::Adam { beta1: opts.betas.0, beta2: opts.betas.1, wd: 0.0, eps: 1e-8, amsgrad: false };
    let mut opt = adam.build(&vs, lr)?;

    let mut reports = Vec::new();
    let steps = train.len().div_ceil(opts.batch) as u64;
    for epoch in start..opts.epochs {
        let t0 = std::time::Instant::now();
        opt.set_lr(lr);
        let mut rng = Rng::new(opts.seed).fork(1 + epoch as u64);
        let mut order: Vec<usize> = (0..train.len()).collect();
        for i in (1..order.len()).rev() {
            order.swap(i, rng.below(i as u64 + 1) as usize);
        }
        let bar = crate::runtime::progress::bar(steps, opts.progress, &format!("epoch {}", epoch + 1));
        let (mut sum, mut count) = (0f64, 0usize);
        for idx in order.chunks(opts.batch) {
            let (x, y, m) = make_batch(train, idx, opts, &mut rng);
            let logits = net.forward_logits(&x);
            let per_pixel = logits.binary_cross_entropy_with_logits::<Tensor>(&y, None, None, Reduction::None);
            let loss = (per_pixel * &m).sum(Kind::Float) / m.sum(Kind::Float).clamp_min(1.0);
            opt.zero_grad();
            loss.backward();
            opt.clip_grad_norm(opts.clip);
            opt.step();
            let l = loss.double_value(&[]);
            if !l.is_finite() {
                return Err(Error::Internal(format!("training loss became {l} in epoch {}", epoch + 1)));
            }
            sum += l;
            count += 1;
            bar.set_message(format!("loss {:.4} (mean {:.4})", l, sum / count as f64));
            bar.inc(1);
        }
        bar.finish_and_clear();
        let t_train = t0.elapsed().as_secs_f64();
        let confusions = evaluate_net(&net, opts.device, val, opts.batch, &THRESHOLDS);
        let (val_05, val_099) = (confusions[0].metrics(), confusions[1].metrics());
        let is_best = best.map_or(true, |b| val_099.miou > b);
        if is_best {
            best = Some(val_099.miou);
        }
        let report = EpochReport {
            epoch: epoch + 1,
            lr,
            train_loss: sum / count.max(1) as f64,
            val_05,
            val_099,
            train_seconds: t_train,
            seconds: t0.elapsed().as_secs_f64(),
            best: is_best,
        };
        lr *= opts.lr_gamma;
        let meta = CheckpointMeta {
            format: crate::nn::checkpoint::FORMAT.into(),
            net: config.clone(),
            epoch: epoch + 1,
            best_metric_name: BEST_METRIC.into(),
            best_metric: best,
            next_lr: lr,
            info: serde_json::json!({"options": opts, "train_examples": train.len(), "val_examples": val.len(), "last_epoch": report}),
        };
        save_correction(&latest, &vs, &meta)?;
        if is_best {
            save_correction(&opts.out.join(BEST), &vs, &meta)?;
        }
        let log = opts.out.join(METRICS_LOG);
        let mut f = std::fs::OpenOptions::new().create(true).append(true).open(&log).map_err(|e| Error::io(&log, e))?;
        writeln!(f, "{}", serde_json::to_string(&report).expect("json")).map_err(|e| Error::io(&log, e))?;
        on_epoch(&report);
        reports.push(report);
    }
    Ok(TrainReport { epochs: reports, first_epoch: start + 1, parameters, best_metric: best })
}
