//! `pointreggpt train descriptor`: train a descriptor of `eval registration` (the patch network, or the
//! MLP on multi-scale FPFH) on pair datasets.

use crate::error::{Error, Result};
use crate::nn::patch_net::PatchNetConfig;
use crate::registration::learned::DescriptorModel;
use crate::registration::patch::PatchConfig;
use crate::training::descriptor::augment::Augment;
use crate::training::descriptor::data::{limit_generated, load_pairs};
use crate::training::descriptor::train::{train_descriptor, DescriptorTrainOptions, LATEST, LOSS_LOG};
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
#[command(
    after_help = "Each step draws --pairs-per-step `ok` pairs and --points per pair: source points with a target point \
within 3.75 cm of where the stored t_target_from_source puts them. With --model patch (the default) both points' \
neighbourhoods become 16^3 truncated-distance patches (1.875 cm voxels, a 30 cm cube) in a local reference frame and a 3D \
ConvNet maps each to a unit vector; with --model fpfh-mlp an MLP (input -> --hidden -> --hidden -> --dim) maps each point's \
FPFH at --fpfh-radii (normals over 5 cm, computed once per cloud) to one. A symmetric InfoNCE loss pulls partners together against the pair's other points (those within 10 cm of the partner are not negatives). \
Every --checkpoint-every steps: <out>/latest.safetensors (network, Adam moments, step; resume with --resume) and a line in \
<out>/loss.jsonl (loss, share of points whose best match is their partner)."
)]
pub struct TrainDescriptorArgs {
    /// Pair dataset(s) made by `pointreggpt build` (folders or object-store URLs; only `ok` rows are used), or
    /// benchmark folders of real pairs with captured poses (`pointreggpt fragments --single-frames` of the
    /// training frames; clouds voxelised at 2.5 cm). Repeat to combine.
    #[arg(long, required = true, value_parser = crate::commands::locations::dataset)]
    pub data: Vec<PathBuf>,
    /// Optimiser steps in total (a resumed run continues up to this count); --epochs sets it from the data.
    #[arg(long, default_value_t = 1500)]
    pub steps: u64,
    #[command(flatten)]
    pub training: DescriptorTrainingArgs,
    /// With both real pairs (benchmark folders) and generated ones (pair datasets) in --data: use at most
    /// this many generated pairs per real pair (a seeded subset; e.g. 8 for the paper's 8:1 mix).
    #[arg(long)]
    pub generated_ratio: Option<f64>,
    /// Pairs per step.
    #[arg(long, default_value_t = 4)]
    pub pairs_per_step: usize,
    /// Corresponding points per pair and step.
    #[arg(long, default_value_t = 64)]
    pub points: usize,
    /// Adam learning rate.
    #[arg(long, default_value_t = 1e-3)]
    pub lr: f64,
    #[command(flatten)]
    pub model: DescriptorModelArgs,
    /// Steps between checkpoints and loss-log lines.
    #[arg(long, default_value_t = 100)]
    pub checkpoint_every: u64,
    /// Seed of the initialisation and of the points drawn.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output folder for checkpoints and the loss log.
    #[arg(long, value_parser = crate::commands::locations::local_output)]
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
    /// Write what training drew to FILE, one JSON line per pair entering a step's loss: step, slot, pair
    /// (index and key), the point counts of the two clouds its patches are made from (after --drop-filled),
    /// the indices of the corresponding points drawn (`source`, `target`) and their coordinates as the
    /// network sees them (`source_xyz`, `target_xyz`, after --noise and --rotation). For checking the options.
    #[arg(long, value_name = "FILE")]
    pub trace_batches: Option<PathBuf>,
}

/// How the descriptor trains on its pairs (shared with `eval boost`): exposure, the known-point rules of
/// generated pairs, augmentation.
#[derive(Debug, Clone, clap::Args)]
pub struct DescriptorTrainingArgs {
    /// Train by exposure: each training pair is drawn this many times on average (the step count follows
    /// the number of pairs, so a larger mix does not show each real pair less often). Overrides --steps.
    #[arg(long)]
    pub epochs: Option<f64>,
    /// Positives only on target points of generated pairs that a sensor saw, re-projected from the source
    /// or seen by the scene (target_known_share + target_scene_share >= 0.5), never on made-up ones. Real
    /// pairs are unaffected; beside --drop-filled it changes nothing (no made-up point is left to draw).
    #[arg(long)]
    pub known_positives: bool,
    /// Drop the made-up target points of generated pairs (target_known_share + target_scene_share < 0.5:
    /// filled by a fill, not re-projected nor seen by the scene) before training, so they enter no local
    /// frame, patch or feature.
    #[arg(long)]
    pub drop_filled: bool,
    /// Gaussian noise added to both clouds' points each time a pair is drawn, sigma in metres (0: none;
    /// GeoTransformer's 3DMatch loader uses 0.005).
    #[arg(long, default_value_t = 0.0)]
    pub noise: f32,
    /// Random rotation of each cloud each time a pair is drawn, up to this many degrees about a random axis
    /// (0: none; 180: any rotation).
    #[arg(long, default_value_t = 0.0)]
    pub rotation: f64,
}

impl DescriptorTrainingArgs {
    /// Sets these options on `opts`.
    pub fn apply(&self, opts: &mut DescriptorTrainOptions) {
        opts.epochs = self.epochs;
        opts.known_positives = self.known_positives;
        opts.drop_filled = self.drop_filled;
        opts.augment = Augment { noise_m: self.noise, rotation_deg: self.rotation };
    }
}

/// Which descriptor network to train (shared with `eval boost`).
#[derive(Debug, Clone, clap::Args)]
pub struct DescriptorModelArgs {
    /// The network: `patch` (a 3D ConvNet on distance-field patches) or `fpfh-mlp` (an MLP on
    /// multi-scale FPFH, the cheap baseline).
    #[arg(long, default_value = "patch", value_parser = ["patch", "fpfh-mlp"])]
    pub model: String,
    /// Descriptor length.
    #[arg(long, default_value_t = 32)]
    pub dim: i64,
    /// patch: channels of the network's first convolution (8: as good as 16 on held-out synthetic pairs
    /// after 60 steps, 0.221 vs 0.234 matching rate, at 2.4x the speed on a CPU).
    #[arg(long, default_value_t = 8)]
    pub width: i64,
    /// fpfh-mlp: width of the two hidden layers.
    #[arg(long, default_value_t = 128)]
    pub hidden: i64,
    /// fpfh-mlp: FPFH radii in metres, comma-separated (33 values each).
    #[arg(long, value_delimiter = ',', default_value = "0.075,0.125,0.2")]
    pub fpfh_radii: Vec<f32>,
}

impl DescriptorModelArgs {
    pub fn model(&self) -> Result<DescriptorModel> {
        let model = match self.model.as_str() {
            "fpfh-mlp" => DescriptorModel::fpfh_mlp(self.fpfh_radii.clone(), self.hidden, self.dim),
            _ => DescriptorModel::Patch {
                net: PatchNetConfig { width: self.width, dim: self.dim, ..Default::default() },
                patch: PatchConfig::default(),
            },
        };
        model.validate("--model")?;
        Ok(model)
    }
}

pub fn run(a: &TrainDescriptorArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    crate::nn::set_torch_threads(a.torch_threads)?;
    let mut opts = DescriptorTrainOptions::new(a.out.clone());
    opts.steps = a.steps;
    a.training.apply(&mut opts);
    opts.pairs_per_step = a.pairs_per_step;
    opts.points_per_pair = a.points;
    opts.lr = a.lr;
    opts.model = a.model.model()?;
    opts.checkpoint_every = a.checkpoint_every;
    opts.seed = a.seed;
    opts.resume = a.resume;
    opts.progress = !a.quiet;
    opts.trace = a.trace_batches.clone();
    opts.validate()?;
    let mut pairs = load_pairs(&a.data)?;
    if let Some(ratio) = a.generated_ratio {
        pairs = limit_generated(pairs, ratio, a.seed)?;
    }
    let real = pairs.iter().filter(|p| p.real).count();
    writeln!(
        out,
        "{} descriptor: {} training pairs ({real} real, {} generated), {} steps of {} pairs x {} points",
        a.model.model,
        pairs.len(),
        pairs.len() - real,
        opts.total_steps(pairs.len()),
        opts.pairs_per_step,
        opts.points_per_pair
    )
    .map_err(w)?;
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
    writeln!(out, "{} parameters; steps {}..={}; checkpoint {}; log {}", report.parameters, report.first_step, report.steps, a.out.join(LATEST).display(), a.out.join(LOSS_LOG).display()).map_err(w)?;
    Ok(())
}
