//! `pointreggpt train descriptor`: train the patch descriptor of `eval registration` on pair datasets.

use crate::error::{Error, Result};
use crate::training::descriptor::data::load_pairs;
use crate::training::descriptor::train::{train_descriptor, DescriptorTrainOptions, LATEST, LOSS_LOG};
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
#[command(
    after_help = "Each step draws --pairs-per-step `ok` pairs and --points per pair: source points with a target point \
within 3.75 cm of where the stored t_target_from_source puts them. Both points' neighbourhoods become 16^3 truncated-distance \
patches (1.875 cm voxels, a 30 cm cube) in a local reference frame, a 3D ConvNet maps each to a unit vector, and a symmetric \
InfoNCE loss pulls partners together against the pair's other points (those within 10 cm of the partner are not negatives). \
Every --checkpoint-every steps: <out>/latest.safetensors (network, Adam moments, step; resume with --resume) and a line in \
<out>/loss.jsonl (loss, share of points whose best match is their partner)."
)]
pub struct TrainDescriptorArgs {
    /// Pair dataset(s) made by `pointreggpt build` (folders or object-store URLs; only `ok` rows are used), or
    /// benchmark folders of real pairs with captured poses (`pointreggpt fragments --single-frames` of the
    /// training frames; clouds voxelised at 2.5 cm). Repeat to combine.
    #[arg(long, required = true)]
    pub data: Vec<PathBuf>,
    /// Optimiser steps in total (a resumed run continues up to this count).
    #[arg(long, default_value_t = 1500)]
    pub steps: u64,
    /// Pairs per step.
    #[arg(long, default_value_t = 4)]
    pub pairs_per_step: usize,
    /// Corresponding points per pair and step.
    #[arg(long, default_value_t = 64)]
    pub points: usize,
    /// Adam learning rate.
    #[arg(long, default_value_t = 1e-3)]
    pub lr: f64,
    /// Descriptor length.
    #[arg(long, default_value_t = 32)]
    pub dim: i64,
    /// Channels of the network's first convolution (8: as good as 16 on held-out synthetic pairs after 60
    /// steps, 0.221 vs 0.234 matching rate, at 2.4x the speed on a CPU).
    #[arg(long, default_value_t = 8)]
    pub width: i64,
    /// Steps between checkpoints and loss-log lines.
    #[arg(long, default_value_t = 100)]
    pub checkpoint_every: u64,
    /// Seed of the initialisation and of the points drawn.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output folder for checkpoints and the loss log.
    #[arg(long)]
    pub out: PathBuf,
    /// Continue from <out>/latest.safetensors (weights, Adam moments, step).
    #[arg(long)]
    pub resume: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// libtorch intra-op threads (see `train correction --help`).
    #[arg(long, default_value_t = 1)]
    pub torch_threads: i32,
}

pub fn run(a: &TrainDescriptorArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    crate::nn::set_torch_threads(a.torch_threads)?;
    let mut opts = DescriptorTrainOptions::new(a.out.clone());
    opts.steps = a.steps;
    opts.pairs_per_step = a.pairs_per_step;
    opts.points_per_pair = a.points;
    opts.lr = a.lr;
    opts.net.dim = a.dim;
    opts.net.width = a.width;
    opts.checkpoint_every = a.checkpoint_every;
    opts.seed = a.seed;
    opts.resume = a.resume;
    opts.progress = !a.quiet;
    opts.validate()?;
    let pairs = load_pairs(&a.data)?;
    writeln!(out, "patch descriptor: {} training pairs, {} steps of {} pairs x {} points", pairs.len(), opts.steps, opts.pairs_per_step, opts.points_per_pair).map_err(w)?;
    writeln!(out, "{:>8} {:>10} {:>9} {:>9}", "step", "loss", "match %", "s").map_err(w)?;
    let mut io_err = None;
    let report = train_descriptor(&pairs, &opts, |r| {
        if let Err(e) = writeln!(out, "{:>8} {:>10.5} {:>9.1} {:>9.1}", r.step, r.loss, 100.0 * r.accuracy, r.seconds) {
            io_err.get_or_insert(e);
        }
    })?;
    if let Some(e) = io_err {
        return Err(w(e));
    }
    writeln!(out, "{} parameters; steps {}..={}; checkpoint {}; log {}", report.parameters, report.first_step, opts.steps, a.out.join(LATEST).display(), a.out.join(LOSS_LOG).display()).map_err(w)?;
    Ok(())
}
