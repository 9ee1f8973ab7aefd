//! `pointreggpt train correction|diffusion|descriptor`: train the depth-correction U-Net on label shards,
//! the diffusion denoiser on depth frames, or (in [`super::train_descriptor`]) the registration descriptor.

use crate::error::{Error, Result};
use crate::training::correction::data::LabelSet;
use crate::training::correction::train::{train_correction, LossPixels, TrainOptions, BEST, BEST_METRIC, LATEST, METRICS_LOG};
use crate::nn::Preset;
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct TrainArgs {
    #[command(subcommand)]
    pub what: TrainWhat,
}

#[derive(Debug, clap::Subcommand)]
pub enum TrainWhat {
    /// Train the depth-correction U-Net (reference §4) on label datasets made by `pointreggpt labels`.
    Correction(TrainCorrectionArgs),
    /// Train the diffusion denoiser (reference §5) on single depth frames of any source.
    Diffusion(TrainDiffusionArgs),
    /// Train the patch descriptor for registration on pair datasets made by `pointreggpt build`.
    Descriptor(super::train_descriptor::TrainDescriptorArgs),
}

#[derive(Debug, clap::Args)]
#[command(
    after_help = "Objective: x0 prediction from x_t = sqrt(abar_t) x0 + sqrt(1 - abar_t) eps (sigmoid schedule -3..3, T 1000), L1 \
weighted by SNR_t (official) or min(SNR_t, 5). Adam (betas 0.9/0.99) written out so its moments are checkpointed, gradient norm \
clipped at 1, EMA 0.995 every 10 steps after 100. Every --checkpoint-every steps: <out>/latest.safetensors (model, EMA, Adam; \
resume with --resume), a line in <out>/loss.jsonl and 4 sample previews <out>/preview-<step>.png; sampling uses the EMA weights. Defaults per preset: paper = official \
(lr 8e-5, batch 32 x 2 accumulation, whole 256x256 frames, 2M steps); tiny = lr 1e-3, batch 8, 64x64 crops (intrinsics \
shifted), min-SNR, 3000 steps."
)]
pub struct TrainDiffusionArgs {
    /// Training frames: a pipeline TOML (its [source], [select] and [working] are used, e.g.
    /// pipelines/demo.toml; its relative paths are relative to its folder) or a folder of depth sequences.
    /// Repeat to combine.
    #[arg(long, required = true)]
    pub data: Vec<PathBuf>,
    /// Network size.
    #[arg(long, value_enum, default_value_t = Preset::Tiny)]
    pub preset: Preset,
    /// Optimiser steps in total (a resumed run continues up to this count).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Frames per forward pass.
    #[arg(long)]
    pub batch: Option<usize>,
    /// Forward passes per optimiser step.
    #[arg(long)]
    pub grad_accum: Option<usize>,
    /// Adam learning rate.
    #[arg(long)]
    pub lr: Option<f64>,
    /// Train on random CROP x CROP windows (0: whole frames).
    #[arg(long)]
    pub crop: Option<usize>,
    /// Loss weight per time step.
    #[arg(long, value_enum)]
    pub weighting: Option<crate::training::diffusion::train::Weighting>,
    /// Train only on time steps 0..MAX_T (default: all 1000). A model for the push-pull-started sampler
    /// (`[inpaint] start = "push_pull"`, `start_step` below MAX_T), which never sees larger steps.
    #[arg(long)]
    pub max_t: Option<usize>,
    /// Hole-aware training, for the push-pull-started sampler (with --max-t): each frame gets the holes a
    /// camera move opens (a round trip through a camera drawn from the build's pivot sampler, its motion
    /// scaled by U(0.1, 1)) and a correction (see --holes-correction), filled by --holes-start, and is noised
    /// from that fill; the loss counts only pixels with true depth, the holes --hole-weight times as much.
    #[arg(long)]
    pub holes: bool,
    /// With --holes: the classical fill of the holes, which the noised start is made from; match the
    /// `[inpaint] start` the model will be sampled from (default push-pull).
    #[arg(long, value_enum)]
    pub holes_start: Option<crate::inpainting::Start>,
    /// Loss weight of hole pixels relative to the others, with --holes.
    #[arg(long)]
    pub hole_weight: Option<f64>,
    /// With --holes: a correction U-Net checkpoint whose drops are part of the holes. Each holed frame goes
    /// through one of: no correction, the official min-pool filter and, with this, the U-Net at tau_m 0.5
    /// and 0.99 (the thresholds of pipelines/demo.toml and paper-3dmatch.toml), drawn uniformly.
    #[arg(long)]
    pub holes_correction: Option<PathBuf>,
    /// No horizontal flips.
    #[arg(long)]
    pub no_flip: bool,
    /// Steps between checkpoints (and loss-log lines and sample previews).
    #[arg(long)]
    pub checkpoint_every: Option<u64>,
    /// No <out>/preview-<step>.png (4 unconditional samples of the EMA network, 20 DDIM steps) at checkpoints.
    #[arg(long)]
    pub no_previews: bool,
    /// Seed of the initialisation, batches, time steps and noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output folder for checkpoints and the loss log.
    #[arg(long, value_parser = crate::commands::locations::local_output)]
    pub out: PathBuf,
    /// Also write the EMA weights alone (what sampling loads; small) to this file at the end.
    #[arg(long, value_parser = crate::commands::locations::local_output)]
    pub export: Option<PathBuf>,
    /// Continue from <out>/latest.safetensors (weights, EMA, Adam moments, step).
    #[arg(long)]
    pub resume: bool,
    /// Fine-tune: start from this checkpoint's weights (its EMA network when it has one; same preset)
    /// with a fresh optimiser, EMA warm-up and step count. Ignored when --resume finds a checkpoint.
    #[arg(long)]
    pub init: Option<PathBuf>,
    /// cpu, cuda or cuda:N.
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// libtorch intra-op threads (see `train correction --help`).
    #[arg(long, default_value_t = 1)]
    pub torch_threads: i32,
}

#[derive(Debug, clap::Args)]
#[command(
    after_help = "Loss: BCE of the keep probability against M_gt; Adam (betas 0.9/0.99), LR x0.95 per epoch, gradient norm \
clipped at 1.0. After every epoch: validation (mIoU, pixel accuracy, FP at tau_m 0.5 and 0.99 over pixels with input depth), \
<out>/latest.safetensors, <out>/best.safetensors (highest validation mIoU at tau_m 0.99) and a line in <out>/metrics.jsonl. \
Defaults per preset: paper = official (lr 4e-5, batch 4, 100 epochs, whole maps, loss over all pixels); tiny = lr 2e-3, batch 8, \
16 epochs, 128x128 random crops, loss over pixels with input depth."
)]
pub struct TrainCorrectionArgs {
    /// Training label dataset(s) made by `pointreggpt labels`: folders or object-store URLs (s3://bucket/prefix, …);
    /// repeat to combine.
    #[arg(long, required = true, value_parser = crate::commands::locations::dataset)]
    pub labels: Vec<PathBuf>,
    /// Validation label dataset(s); without, the last --val-fraction of the training windows is held out.
    #[arg(long, value_parser = crate::commands::locations::dataset)]
    pub val_labels: Vec<PathBuf>,
    /// Fraction of fused windows held out for validation when no --val-labels is given.
    #[arg(long, default_value_t = 0.1)]
    pub val_fraction: f64,
    /// Network size.
    #[arg(long, value_enum, default_value_t = Preset::Tiny)]
    pub preset: Preset,
    /// Epochs in total (a resumed run continues up to this count).
    #[arg(long)]
    pub epochs: Option<u32>,
    /// Maps per optimiser step.
    #[arg(long)]
    pub batch: Option<usize>,
    /// Initial learning rate.
    #[arg(long)]
    pub lr: Option<f64>,
    /// Train on random CROP x CROP windows (0: whole maps).
    #[arg(long)]
    pub crop: Option<usize>,
    /// Pixels the loss averages over.
    #[arg(long, value_enum)]
    pub loss_pixels: Option<LossPixels>,
    /// Loss weight of the pixels labelled "drop" (1 = official). About 2.5 moves the network's 0.5 keep
    /// probability to where the mIoU at tau_m 0.5 is highest (drops are ~7 % of the pixels).
    #[arg(long, default_value_t = 1.0)]
    pub drop_weight: f64,
    /// Random horizontal flips of training maps.
    #[arg(long)]
    pub hflip: bool,
    /// Seed of the initialisation, data order and crops.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Feed the depth alone (no DepthAugment channels).
    #[arg(long)]
    pub no_augment: bool,
    /// Output folder for checkpoints and the metrics log.
    #[arg(long, value_parser = crate::commands::locations::local_output)]
    pub out: PathBuf,
    /// Continue from <out>/latest.safetensors (weights, epoch and learning rate; Adam's moments restart).
    #[arg(long)]
    pub resume: bool,
    /// cpu, cuda or cuda:N.
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// libtorch intra-op threads. 1 by default: on a shared or small machine more threads than idle cores
    /// make libtorch's OpenMP workers spin (a 2-core machine with one other busy process ran a training step
    /// 5-10x slower with 2 threads than with 1).
    #[arg(long, default_value_t = 1)]
    pub torch_threads: i32,
}

pub fn run(args: &TrainArgs, out: &mut dyn Write) -> Result<()> {
    match &args.what {
        TrainWhat::Correction(a) => run_correction(a, out),
        TrainWhat::Diffusion(a) => run_diffusion(a, out),
        TrainWhat::Descriptor(a) => super::train_descriptor::run(a, out),
    }
}

fn run_correction(a: &TrainCorrectionArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    crate::nn::set_torch_threads(a.torch_threads)?;
    let mut opts = TrainOptions::for_preset(a.preset, a.out.clone());
    opts.augment = !a.no_augment;
    opts.epochs = a.epochs.unwrap_or(opts.epochs);
    opts.batch = a.batch.unwrap_or(opts.batch);
    opts.lr = a.lr.unwrap_or(opts.lr);
    if let Some(c) = a.crop {
        opts.crop = (c > 0).then_some(c);
    }
    opts.loss_pixels = a.loss_pixels.unwrap_or(opts.loss_pixels);
    opts.drop_weight = a.drop_weight;
    opts.hflip = a.hflip;
    opts.seed = a.seed;
    opts.resume = a.resume;
    opts.device = crate::nn::parse_device(&a.device)?;
    opts.progress = !a.quiet;
    if !(a.val_fraction > 0.0 && a.val_fraction < 1.0) {
        return Err(Error::config("--val-fraction", "must be in (0, 1)"));
    }
    let set = LabelSet::open_all(&a.labels)?;
    let (train, val) = if a.val_labels.is_empty() {
        set.split_windows(a.val_fraction)
    } else {
        (set, LabelSet::open_all(&a.val_labels)?)
    };
    let (px, drop) = train.pixel_counts();
    writeln!(
        out,
        "correction U-Net: preset {}, augment {}, {} training maps ({}x{}, {:.1}% of {} depth pixels labelled drop), {} validation maps",
        a.preset.as_str(),
        opts.augment,
        train.len(),
        train.width,
        train.height,
        100.0 * drop as f64 / px.max(1) as f64,
        px,
        val.len()
    )
    .map_err(w)?;
    writeln!(
        out,
        "{:>5} {:>9} {:>10} {:>10} {:>10} {:>12} {:>8} {:>8}",
        "epoch", "lr", "loss", "mIoU@0.5", "mIoU@0.99", "FP/map@0.99", "train s", "total s"
    )
    .map_err(w)?;
    let t0 = std::time::Instant::now();
    let mut io_err = None;
    let report = train_correction(&train, &val, &opts, |r| {
        let line = format!(
            "{:>5} {:>9.2e} {:>10.5} {:>10.2} {:>10.2} {:>12.1} {:>8.1} {:>8.1}{}",
            r.epoch,
            r.lr,
            r.train_loss,
            100.0 * r.val_05.miou,
            100.0 * r.val_099.miou,
            r.val_099.fp_per_map,
            r.train_seconds,
            r.seconds,
            if r.best { "  best" } else { "" }
        );
        if let Err(e) = writeln!(out, "{line}") {
            io_err.get_or_insert(e);
        }
    })?;
    if let Some(e) = io_err {
        return Err(w(e));
    }
    writeln!(
        out,
        "{} parameters; trained epochs {}..={} in {:.1} s",
        report.parameters,
        report.first_epoch,
        opts.epochs,
        t0.elapsed().as_secs_f64()
    )
    .map_err(w)?;
    writeln!(
        out,
        "checkpoints: {} (every epoch), {} ({BEST_METRIC} {}); log {}",
        a.out.join(LATEST).display(),
        a.out.join(BEST).display(),
        report.best_metric.map_or("-".into(), |b| format!("{:.4}", b)),
        a.out.join(METRICS_LOG).display()
    )
    .map_err(w)?;
    Ok(())
}

fn run_diffusion(a: &TrainDiffusionArgs, out: &mut dyn Write) -> Result<()> {
    use crate::training::diffusion::data::FrameSet;
    use crate::training::diffusion::train::{train_diffusion, DiffusionTrainOptions, LATEST, LOSS_LOG};
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    crate::nn::set_torch_threads(a.torch_threads)?;
    let mut opts = DiffusionTrainOptions::for_preset(a.preset, a.out.clone());
    opts.steps = a.steps.unwrap_or(opts.steps);
    opts.batch = a.batch.unwrap_or(opts.batch);
    opts.grad_accum = a.grad_accum.unwrap_or(opts.grad_accum);
    opts.lr = a.lr.unwrap_or(opts.lr);
    if let Some(c) = a.crop {
        opts.crop = (c > 0).then_some(c);
    }
    opts.weighting = a.weighting.unwrap_or(opts.weighting);
    opts.max_t = a.max_t.or(opts.max_t);
    opts.holes = a.holes;
    opts.hole_weight = a.hole_weight.unwrap_or(opts.hole_weight);
    opts.hole_start = a.holes_start.unwrap_or(opts.hole_start);
    if !a.holes && (a.holes_correction.is_some() || a.hole_weight.is_some() || a.holes_start.is_some()) {
        return Err(Error::config("--holes-correction/--hole-weight/--holes-start", "only apply with --holes"));
    }
    if let Some(path) = &a.holes_correction {
        let checkpoint = crate::nn::ModelPath::new(&path.display().to_string());
        for threshold in crate::training::diffusion::holes::UNET_THRESHOLDS {
            opts.hole_corrections.push(crate::correction::CorrectionConfig::Unet { checkpoint, threshold, preset: None });
        }
    }
    opts.hflip = !a.no_flip;
    opts.checkpoint_every = a.checkpoint_every.unwrap_or(opts.checkpoint_every);
    opts.previews = !a.no_previews;
    opts.seed = a.seed;
    opts.resume = a.resume;
    opts.init = a.init.clone();
    opts.device = crate::nn::parse_device(&a.device)?;
    opts.progress = !a.quiet;
    let data = FrameSet::load(&a.data, opts.progress)?;
    writeln!(
        out,
        "diffusion denoiser: preset {}, {} training frames ({}x{}), {} steps of batch {} x {}",
        a.preset.as_str(),
        data.len(),
        data.width,
        data.height,
        opts.steps,
        opts.batch,
        opts.grad_accum
    )
    .map_err(w)?;
    writeln!(out, "{:>8} {:>10} {:>10} {:>9}", "step", "loss", "grad norm", "s").map_err(w)?;
    let mut io_err = None;
    let report = train_diffusion(&data, &opts, |r| {
        if let Err(e) = writeln!(out, "{:>8} {:>10.5} {:>10.4} {:>9.1}", r.step, r.loss, r.grad_norm, r.seconds) {
            io_err.get_or_insert(e);
        }
    })?;
    if let Some(e) = io_err {
        return Err(w(e));
    }
    let latest = a.out.join(LATEST);
    writeln!(out, "{} parameters; steps {}..={}; checkpoint {}; log {}", report.parameters, report.first_step, opts.steps, latest.display(), a.out.join(LOSS_LOG).display()).map_err(w)?;
    if let Some(path) = &a.export {
        crate::diffusion::checkpoint::export_ema(&latest, path)?;
        writeln!(out, "EMA weights: {}", path.display()).map_err(w)?;
    }
    Ok(())
}
