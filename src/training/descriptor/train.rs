//! The descriptor's training loop: per step, corresponding points of a few pairs, the network's input
//! at them in the two clouds (patches, or FPFH rows computed once per cloud), and a symmetric InfoNCE
//! loss within each pair (the partner is the positive; points of the same pair farther than the negative
//! radius from it are the negatives). Adam with its moments in the checkpoint, so `--resume` continues
//! exactly; the per-step randomness comes from (seed, step).

use super::augment::{drop_filled, Augment};
use super::data::{correspondences, TrainPair};
use crate::error::{Error, Result};
use crate::geometry::{Point, RadiusIndex};
use crate::registration::learned::{load_into, read_meta, save, DescriptorMeta, DescriptorModel, DescriptorNet, Prepared, FORMAT};
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
/// The sub-stream of a step's RNG the augmentation of each drawn pair forks (at the RNG's state then).
const AUGMENT_STREAM: u64 = 0xA06;

/// Everything a training run needs besides the data.
#[derive(Clone, Debug, Serialize)]
pub struct DescriptorTrainOptions {
    pub model: DescriptorModel,
    /// Optimiser steps in total (a resumed run continues up to this count), unless `epochs` is set.
    pub steps: u64,
    /// Training by exposure: the step count follows the data, so that each training pair is drawn this
    /// many times on average (steps = ⌈epochs × pairs / pairs per step⌉); adding pairs to a mix then no
    /// longer shows each real pair fewer times.
    pub epochs: Option<f64>,
    /// Positives only on observed target points of generated pairs (re-projected or seen by the scene:
    /// [`super::data::TrainPair::target_observed`] ≥ 0.5); real pairs and datasets without provenance are
    /// unaffected.
    pub known_positives: bool,
    /// Drop the made-up target points of generated pairs (neither re-projected nor seen by the scene)
    /// before training: they then appear in no local frame, patch, feature or negative.
    pub drop_filled: bool,
    /// Noise and rotation applied each time a pair is drawn.
    pub augment: Augment,
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
    /// Write one [`BatchTrace`] line (JSON) per drawn pair that enters the loss to this file (created
    /// anew; the steps this call runs): what training drew and fed the network, for checking the options.
    #[serde(skip)]
    pub trace: Option<PathBuf>,
}

impl DescriptorTrainOptions {
    pub fn new(out: PathBuf) -> Self {
        DescriptorTrainOptions {
            model: DescriptorModel::default(),
            steps: 1500,
            epochs: None,
            known_positives: false,
            drop_filled: false,
            augment: Augment::default(),
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
            trace: None,
        }
    }

    /// The steps a run on `pairs` training pairs takes: `steps`, or the exposure `epochs` asks for.
    pub fn total_steps(&self, pairs: usize) -> u64 {
        match self.epochs {
            Some(e) => ((e * pairs as f64) / self.pairs_per_step as f64).ceil().max(1.0) as u64,
            None => self.steps,
        }
    }

    pub fn validate(&self) -> Result<()> {
        self.model.validate("descriptor")?;
        if self.steps == 0 || self.pairs_per_step == 0 || self.points_per_pair < 2 || self.checkpoint_every == 0 {
            return Err(Error::config("descriptor", "steps, pairs per step and checkpoint interval must be positive, points per pair at least 2"));
        }
        if self.epochs.is_some_and(|e| !(e.is_finite() && e > 0.0)) {
            return Err(Error::config("--epochs", "must be a positive number"));
        }
        if !(self.augment.noise_m.is_finite() && self.augment.noise_m >= 0.0 && self.augment.noise_m <= 0.1) {
            return Err(Error::config("--noise", "must be 0..=0.1 metres"));
        }
        if !(0.0..=180.0).contains(&self.augment.rotation_deg) {
            return Err(Error::config("--rotation", "must be 0..=180 degrees"));
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

/// One line of the batch trace ([`DescriptorTrainOptions::trace`], `train descriptor --trace-batches`):
/// one drawn pair of one step as the network saw it, after `drop_filled` and augmentation: the sizes of
/// the two clouds its patches (or features) are made from, the corresponding points drawn (indices into
/// those clouds; row i of each are partners) and their coordinates.
#[derive(Clone, Debug, Serialize)]
pub struct BatchTrace<'a> {
    pub step: u64,
    /// The draw within the step (0..pairs per step).
    pub slot: usize,
    /// Index of the pair in the training pairs (the order `--data` loads them).
    pub pair: usize,
    pub key: &'a str,
    pub source_points: usize,
    pub target_points: usize,
    pub source: &'a [usize],
    pub target: &'a [usize],
    pub source_xyz: Vec<[f32; 3]>,
    pub target_xyz: Vec<[f32; 3]>,
}

impl<'a> BatchTrace<'a> {
    /// The record of `pair` (number `index` of the training pairs, as drawn: dropped and augmented) fed
    /// with the partners `source[i]`, `target[i]`.
    pub fn new(step: u64, slot: usize, index: usize, pair: &'a TrainPair, source: &'a [usize], target: &'a [usize]) -> Self {
        let xyz = |cloud: &[Point], idx: &[usize]| idx.iter().map(|&i| [cloud[i].x, cloud[i].y, cloud[i].z]).collect();
        BatchTrace {
            step,
            slot,
            pair: index,
            key: &pair.key,
            source_points: pair.source.len(),
            target_points: pair.target.len(),
            source,
            target,
            source_xyz: xyz(&pair.source, source),
            target_xyz: xyz(&pair.target, target),
        }
    }
}

/// Result of a run.
pub struct DescriptorTrainReport {
    pub first_step: u64,
    /// The run's last step (`steps`, or what `epochs` resolved to).
    pub steps: u64,
    pub parameters: i64,
    pub final_loss: f64,
}

/// Trains (or resumes) a descriptor on `pairs`, writing checkpoints and the loss log to `opts.out`.
pub fn train_descriptor(pairs: &[TrainPair], opts: &DescriptorTrainOptions, mut on_report: impl FnMut(&StepReport)) -> Result<DescriptorTrainReport> {
    opts.validate()?;
    if pairs.is_empty() {
        return Err(Error::config("--data", "no training pairs"));
    }
    std::fs::create_dir_all(&opts.out).map_err(|e| Error::io(&opts.out, e))?;
    let dropped: Vec<TrainPair>;
    let pairs = if opts.drop_filled {
        dropped = pairs.iter().map(drop_filled).collect();
        &dropped[..]
    } else {
        pairs
    };
    let steps = opts.total_steps(pairs.len());
    let augmenting = !opts.augment.is_off();
    tch::manual_seed(opts.seed as i64);
    let mut vs = nn::VarStore::new(Device::Cpu);
    let net = DescriptorNet::new(&vs.root(), &opts.model)?;
    let mut vars: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
    vars.sort_by(|a, b| a.0.cmp(&b.0));
    let mut adam = Adam::new(&vars, opts.lr, (0.9, 0.999));
    let latest = opts.out.join(LATEST);
    let mut start = 0;
    if opts.resume && latest.exists() {
        let meta = read_meta(&latest)?;
        if meta.model != opts.model {
            return Err(Error::config("--resume", format!("{} holds another network ({:?})", latest.display(), meta.model)));
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
    // Without augmentation the clouds never change: index the targets once, and FPFH of every cloud once
    // (33 floats per point and radius in memory); patch indexes per step.
    let targets: Vec<RadiusIndex> =
        if augmenting { Vec::new() } else { pairs.iter().map(|p| RadiusIndex::new(&p.target, opts.positive_radius_m)).collect() };
    let cached: Vec<[Prepared; 2]> = if net.worth_caching() && !augmenting {
        let bar = crate::runtime::progress::bar(pairs.len() as u64, opts.progress, "pair");
        bar.set_message("input features");
        let c = pairs.iter().map(|p| [net.prepare(&p.source), net.prepare(&p.target)]);
        let c = c.inspect(|_| bar.inc(1)).collect();
        bar.finish_and_clear();
        c
    } else {
        Vec::new()
    };
    let mut trace = match &opts.trace {
        Some(path) => Some((path, std::io::BufWriter::new(std::fs::File::create(path).map_err(|e| Error::io(path, e))?))),
        None => None,
    };
    let log_path = opts.out.join(LOSS_LOG);
    let mut log = std::fs::OpenOptions::new().create(true).append(true).open(&log_path).map_err(|e| Error::io(&log_path, e))?;
    let bar = crate::runtime::progress::bar(steps, opts.progress, "step");
    bar.set_position(start);
    let t0 = std::time::Instant::now();
    let (mut sum, mut hits, mut count, mut last) = (0f64, 0f64, 0u64, f64::NAN);
    for step in start + 1..=steps {
        let mut rng = Rng::new(opts.seed).fork(step);
        let mut step_loss = 0.0;
        let mut step_hits = 0.0;
        for slot in 0..opts.pairs_per_step {
            let k = rng.below(pairs.len() as u64) as usize;
            let (augmented, fresh_index);
            let (pair, index) = if augmenting {
                augmented = opts.augment.apply(&pairs[k], &mut rng.fork(AUGMENT_STREAM));
                fresh_index = RadiusIndex::new(&augmented.target, opts.positive_radius_m);
                (&augmented, &fresh_index)
            } else {
                (&pairs[k], &targets[k])
            };
            let c = correspondences(pair, index, opts.points_per_pair, opts.known_positives, &mut rng);
            if c.len() < 2 {
                continue;
            }
            let (si, ti): (Vec<usize>, Vec<usize>) = c.into_iter().unzip();
            if let Some((path, w)) = &mut trace {
                let line = serde_json::to_string(&BatchTrace::new(step, slot, k, pair, &si, &ti)).expect("json");
                writeln!(w, "{line}").map_err(|e| Error::io(path, e))?;
            }
            let fresh;
            let [ps, pt] = match cached.get(k) {
                Some(both) => both,
                None => {
                    fresh = [net.prepare(&pair.source), net.prepare(&pair.target)];
                    &fresh
                }
            };
            let (xs, xt) = (net.input(ps, &pair.source, &si), net.input(pt, &pair.target, &ti));
            let tp: Vec<Point> = ti.iter().map(|&i| pair.target[i]).collect();
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
        if step % opts.checkpoint_every == 0 || step == steps {
            let report = StepReport { step, loss: sum / count as f64, accuracy: hits / count as f64, seconds: t0.elapsed().as_secs_f64() };
            writeln!(log, "{}", serde_json::to_string(&report).expect("json")).map_err(|e| Error::io(&log_path, e))?;
            let meta = DescriptorMeta {
                format: FORMAT.into(),
                model: opts.model.clone(),
                step,
                info: serde_json::json!({"options": opts, "pairs": pairs.len(), "steps": steps, "last_loss": report.loss}),
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
    if let Some((path, mut w)) = trace {
        w.flush().map_err(|e| Error::io(path, e))?;
    }
    let parameters = vars.iter().map(|(_, t)| t.numel() as i64).sum();
    Ok(DescriptorTrainReport { first_step: start + 1, steps, parameters, final_loss: last })
}
