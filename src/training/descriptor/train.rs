//! The descriptor's training loop: per step, corresponding points of a few pairs, their patches in the
//! two clouds, and a symmetric InfoNCE loss within each pair (the partner is the positive; points of the
//! same pair farther than the negative radius from it are the negatives). Adam with its moments in the
//! checkpoint, so `--resume` continues exactly; the per-step randomness comes from (seed, step).

use super::data::{correspondences, TrainPair};
use crate::registration::learned::{load_into, read_meta, save, DescriptorMeta, FORMAT};
use crate::registration::patch::{patches, PatchConfig};
use crate::error::{Error, Result};
use crate::geometry::{Point, RadiusIndex};
use crate::nn::patch_net::{PatchNet, PatchNetConfig};
use crate::rng::Rng;
use crate::training::optim::Adam;
use serde::Serialize;
use std::io::Write;
use std::path::PathBuf;
use tch::{nn, Device, Kind, Tensor};

/// The checkpoint written every `checkpoint_every` steps and at the end.
pub const LATEST: &str = "latest.safetensors";
/// The loss log (JSON lines).
pub const LOSS_LOG: &str = "loss.jsonl";

/// Everything a training run needs besides the data.
#[derive(Clone, Debug, Serialize)]
pub struct DescriptorTrainOptions {
    pub net: PatchNetConfig,
    pub patch: PatchConfig,
    /// Optimiser steps in total (a resumed run continues up to this count).
    pub steps: u64,
    /// Pairs per step.
    pub pairs_per_step: usize,
    /// Corresponding points per pair and step.
    pub points_per_pair: usize,
    pub lr: f64,
    /// Softmax temperature of the InfoNCE loss.
    pub temperature: f64,
    /// A target point this close to where the pose puts a source point is its partner (3DMatch: 3.75 cm).
    pub positive_radius_m: f32,
    /// Points closer than this to a point's partner are not its negatives.
    pub negative_radius_m: f32,
    pub clip: f64,
    pub seed: u64,
    pub checkpoint_every: u64,
    #[serde(skip)]
    pub out: PathBuf,
    pub resume: bool,
    #[serde(skip)]
    pub progress: bool,
}

impl DescriptorTrainOptions {
    pub fn new(out: PathBuf) -> Self {
        DescriptorTrainOptions {
            net: PatchNetConfig::default(),
            patch: PatchConfig::default(),
            steps: 1500,
            pairs_per_step: 4,
            points_per_pair: 64,
            lr: 1e-3,
            temperature: 0.07,
            positive_radius_m: 0.0375,
            negative_radius_m: 0.10,
            clip: 1.0,
            seed: 0,
            checkpoint_every: 100,
            out,
            resume: false,
            progress: false,
        }
    }

    pub fn validate(&self) -> Result<()> {
        self.patch.validate("descriptor.patch")?;
        if self.net.voxels != self.patch.voxels as i64 {
            return Err(Error::config("descriptor", format!("the network takes {}³ patches, the patches have {}³ voxels", self.net.voxels, self.patch.voxels)));
        }
        if self.steps == 0 || self.pairs_per_step == 0 || self.points_per_pair < 2 || self.checkpoint_every == 0 {
            return Err(Error::config("descriptor", "steps, pairs per step and checkpoint interval must be positive, points per pair at least 2"));
        }
        if !(self.lr > 0.0 && self.temperature > 0.0 && self.positive_radius_m > 0.0 && self.negative_radius_m >= self.positive_radius_m) {
            return Err(Error::config("descriptor", "lr, temperature and the positive radius must be positive, the negative radius at least the positive one"));
        }
        Ok(())
    }
}

/// One line of the loss log: means over the steps since the previous line.
#[derive(Clone, Debug, Serialize)]
pub struct StepReport {
    pub step: u64,
    pub loss: f64,
    /// Share of points whose most similar target patch in the step is their partner.
    pub accuracy: f64,
    pub seconds: f64,
}

/// The InfoNCE loss of one pair's descriptors (`s`, `t`: `[n, dim]`, row i of each describing partners)
/// with `negative[i][j]` false where j must not count as i's negative, and the share of rows whose best
/// match is their partner.
pub fn info_nce(s: &Tensor, t: &Tensor, not_negative: &Tensor, temperature: f64) -> (Tensor, f64) {
    let n = s.size()[0];
    let logits = (s.matmul(&t.transpose(0, 1)) / temperature).masked_fill(not_negative, -1e4);
    let labels = Tensor::arange(n, (Kind::Int64, Device::Cpu));
    let loss = (logits.cross_entropy_for_logits(&labels) + logits.transpose(0, 1).cross_entropy_for_logits(&labels)) * 0.5;
    let hits = logits.argmax(1, false).eq_tensor(&labels).to_kind(Kind::Float).mean(Kind::Float).double_value(&[]);
    (loss, hits)
}

/// `[n, n]` true where j ≠ i lies within `radius` of i (target points): not a negative of i.
fn near_mask(targets: &[Point], radius: f32) -> Tensor {
    let n = targets.len();
    let mut mask = vec![false; n * n];
    for i in 0..n {
        for j in 0..n {
            mask[i * n + j] = i != j && (targets[i] - targets[j]).norm() < radius;
        }
    }
    Tensor::from_slice(&mask).view([n as i64, n as i64])
}

/// Result of a run.
pub struct DescriptorTrainReport {
    pub first_step: u64,
    pub parameters: i64,
    pub final_loss: f64,
}

/// Trains (or resumes) a patch descriptor on `pairs`, writing checkpoints and the loss log to `opts.out`.
pub fn train_descriptor(pairs: &[TrainPair], opts: &DescriptorTrainOptions, mut on_report: impl FnMut(&StepReport)) -> Result<DescriptorTrainReport> {
    opts.validate()?;
    if pairs.is_empty() {
        return Err(Error::config("--data", "no training pairs"));
    }
    std::fs::create_dir_all(&opts.out).map_err(|e| Error::io(&opts.out, e))?;
    tch::manual_seed(opts.seed as i64);
    let mut vs = nn::VarStore::new(Device::Cpu);
    let net = PatchNet::new(&vs.root(), &opts.net)?;
    let mut vars: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
    vars.sort_by(|a, b| a.0.cmp(&b.0));
    let mut adam = Adam::new(&vars, opts.lr, (0.9, 0.999));
    let latest = opts.out.join(LATEST);
    let mut start = 0;
    if opts.resume && latest.exists() {
        let meta = read_meta(&latest)?;
        if meta.net != opts.net || meta.patch != opts.patch {
            return Err(Error::config("--resume", format!("{} holds another network or patch ({:?}, {:?})", latest.display(), meta.net, meta.patch)));
        }
        let rest = load_into(&latest, &mut vs)?;
        for (prefix, moments) in [("opt.m.", &mut adam.m), ("opt.v.", &mut adam.v)] {
            for (name, m) in moments.iter_mut() {
                let t = rest.get(&format!("{prefix}{name}")).ok_or_else(|| Error::input(&latest, format!("missing optimiser state `{prefix}{name}`")))?;
                tch::no_grad(|| m.copy_(t));
            }
        }
        start = meta.step;
    }
    let targets: Vec<RadiusIndex> = pairs.iter().map(|p| RadiusIndex::new(&p.target, opts.positive_radius_m)).collect();
    let log_path = opts.out.join(LOSS_LOG);
    let mut log = std::fs::OpenOptions::new().create(true).append(true).open(&log_path).map_err(|e| Error::io(&log_path, e))?;
    let bar = crate::runtime::progress::bar(opts.steps, opts.progress, "step");
    bar.set_position(start);
    let t0 = std::time::Instant::now();
    let (mut sum, mut hits, mut count, mut last) = (0f64, 0f64, 0u64, f64::NAN);
    let n = opts.patch.voxels as i64;
    for step in start + 1..=opts.steps {
        let mut rng = Rng::new(opts.seed).fork(step);
        let mut step_loss = 0.0;
        let mut step_hits = 0.0;
        for _ in 0..opts.pairs_per_step {
            let k = rng.below(pairs.len() as u64) as usize;
            let c = correspondences(&pairs[k], &targets[k], opts.points_per_pair, &mut rng);
            if c.len() < 2 {
                continue;
            }
            let (sp, tp): (Vec<Point>, Vec<Point>) = c.into_iter().unzip();
            let m = sp.len() as i64;
            let xs = Tensor::from_slice(&patches(&pairs[k].source, &sp, &opts.patch)).view([m, 1, n, n, n]);
            let xt = Tensor::from_slice(&patches(&pairs[k].target, &tp, &opts.patch)).view([m, 1, n, n, n]);
            let (loss, h) = info_nce(&net.forward(&xs), &net.forward(&xt), &near_mask(&tp, opts.negative_radius_m), opts.temperature);
            let loss = loss / opts.pairs_per_step as f64;
            loss.backward();
            step_loss += loss.double_value(&[]);
            step_hits += h / opts.pairs_per_step as f64;
        }
        if !step_loss.is_finite() {
            return Err(Error::Internal(format!("descriptor loss became {step_loss} at step {step}")));
        }
        adam.step(&vars, step, opts.clip);
        (sum, hits, count, last) = (sum + step_loss, hits + step_hits, count + 1, step_loss);
        bar.set_message(format!("loss {:.4}", sum / count as f64));
        bar.inc(1);
        if step % opts.checkpoint_every == 0 || step == opts.steps {
            let report = StepReport { step, loss: sum / count as f64, accuracy: hits / count as f64, seconds: t0.elapsed().as_secs_f64() };
            writeln!(log, "{}", serde_json::to_string(&report).expect("json")).map_err(|e| Error::io(&log_path, e))?;
            let meta = DescriptorMeta {
                format: FORMAT.into(),
                net: opts.net,
                patch: opts.patch,
                step,
                info: serde_json::json!({"options": opts, "pairs": pairs.len(), "last_loss": report.loss}),
            };
            let moments: Vec<(String, Tensor)> = [("opt.m.", &adam.m), ("opt.v.", &adam.v)]
                .iter()
                .flat_map(|(prefix, named)| named.iter().map(move |(k, t)| (format!("{prefix}{k}"), t.shallow_clone())))
                .collect();
            save(&latest, &vs, &moments, &meta)?;
            on_report(&report);
            (sum, hits, count) = (0.0, 0.0, 0);
        }
    }
    bar.finish_and_clear();
    let parameters = vars.iter().map(|(_, t)| t.numel() as i64).sum();
    Ok(DescriptorTrainReport { first_step: start + 1, parameters, final_loss: last })
}
