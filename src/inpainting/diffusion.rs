//! The diffusion inpainter: the trained denoiser sampled with DDIM and the range–null-space step
//! ([`crate::diffusion::sampler`]), so the known pixels of the output are the input's.

use super::{Background, InpaintContext, Inpainter, PushPull};
use crate::nn::space::{from_network, to_network};
use crate::diffusion::sampler::{ddnm_sample, Problem, Resample, SamplerOptions};
use crate::diffusion::schedule::Schedule;
use crate::diffusion::model::{is_torchscript, load_model, NativeModel, X0Model};
use crate::error::{Error, Result};
use crate::geometry::DepthMap;
use crate::nn::denoiser::Denoiser;
use crate::nn::ModelPath;
use serde::{Deserialize, Serialize};
use std::sync::Mutex;
use tch::{nn, Device};

/// `[inpaint] method = "diffusion"`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DiffusionInpaintConfig {
    /// Denoiser checkpoint (`pointreggpt train diffusion`, or the authors' weights converted to
    /// safetensors) or a TorchScript denoiser `forward(x, t, intrinsics) → x0` (in a config file relative
    /// to the file's folder), or a built-in model (`builtin:models/diffusion-tiny-holes.safetensors`).
    pub checkpoint: ModelPath,
    /// DDIM steps (paper 250); with `start = "push_pull"` at most `start_step + 1`.
    pub steps: usize,
    /// DDIM η (official 1.0).
    #[serde(default = "official_eta")]
    pub eta: f64,
    /// Where the chain starts: `noise` (official: pure noise at step 999), `push_pull` or `background`
    /// (the known pixels and that classical fill, noised to `start_step`; the measurements are in
    /// `docs/lab/`, from `docs/diffusion.md`).
    #[serde(default)]
    pub start: Start,
    /// The step a `push_pull` start is noised to (0..=999).
    #[serde(default = "default_start_step")]
    pub start_step: usize,
    /// Views per forward pass (the authors' generator: 4). Every forward pass has exactly this many views
    /// (a short batch is padded), so a view's result does not depend on which views share its batch;
    /// results differ from another batch size by float rounding (~1e-6), hence part of the config.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub batch: usize,
    /// RePaint-style resampling, `{ jump = J, repeats = R }`: every block of J DDIM steps runs R times,
    /// re-noised back to its first step in between (not in the official sampler; docs/diffusion.md).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resample: Option<Resample>,
}

fn one() -> usize {
    1
}

fn is_one(n: &usize) -> bool {
    *n == 1
}

/// The initial state of the sampling chain.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Start {
    /// Pure noise at the last step (official).
    #[default]
    Noise,
    /// The known pixels and a push–pull fill, noised to `start_step`.
    PushPull,
    /// The known pixels and the background fill ([`Background`]), noised to `start_step`.
    Background,
}

impl Start {
    /// The classical fill a chain with a start step starts from: the background fill for `background`,
    /// push–pull otherwise (a `noise` chain with a start step, and hole-aware training's default).
    pub fn classical_fill(self) -> &'static dyn Inpainter {
        if self == Start::Background {
            &Background
        } else {
            &PushPull
        }
    }
}

fn official_eta() -> f64 {
    SamplerOptions::OFFICIAL.eta
}

fn default_start_step() -> usize {
    500
}

impl DiffusionInpaintConfig {
    pub fn validate(&self, field: &str) -> Result<()> {
        if self.steps == 0 || self.steps > 1000 {
            return Err(Error::config(field, "steps must be in 1..=1000"));
        }
        if !(self.eta >= 0.0 && self.eta <= 1.0) {
            return Err(Error::config(field, "eta must be in [0, 1]"));
        }
        if self.start_step > 999 {
            return Err(Error::config(field, "start_step must be in 0..=999"));
        }
        // From step s the chain has s + 1 distinct steps left (s, s − 1, …, 0); more would repeat steps.
        if self.start != Start::Noise && self.steps > self.start_step + 1 {
            return Err(Error::config(
                field,
                format!(
                    "steps = {} is more than a classical start at start_step = {} can run: at most start_step + 1 = {} \
                     steps (lower steps or raise start_step)",
                    self.steps,
                    self.start_step,
                    self.start_step + 1
                ),
            ));
        }
        if self.resample.is_some_and(|r| r.jump == 0 || r.repeats == 0 || r.repeats > 100) {
            return Err(Error::config(field, "resample needs jump >= 1 and repeats in 1..=100"));
        }
        if self.batch == 0 || self.batch > 256 {
            return Err(Error::config(field, "batch must be in 1..=256"));
        }
        let path = self.checkpoint.as_path();
        let checked = match is_torchscript(path) {
            Ok(true) => load_model(path, Device::Cpu).map(|_| None),
            Ok(false) => crate::diffusion::checkpoint::read_meta(path).map(|m| m.trained_below_step()),
            Err(e) => Err(e),
        };
        let trained_below = checked.map_err(|e| Error::config(field, format!("checkpoint `{}`: {e}", self.checkpoint)))?;
        match (trained_below, self.sampler().start_step) {
            (Some(cap), start) if start.is_none_or(|s| s >= cap) => Err(Error::config(
                field,
                format!(
                    "checkpoint `{}` was trained only on time steps below {cap} (--max-t): sample it with \
                     start = \"push_pull\" or \"background\" and start_step < {cap}",
                    self.checkpoint
                ),
            )),
            _ => Ok(()),
        }
    }

    pub fn sampler(&self) -> SamplerOptions {
        let start_step = (self.start != Start::Noise).then_some(self.start_step);
        SamplerOptions { steps: self.steps, eta: self.eta, start_step, resample: self.resample }
    }
}

/// A loaded denoiser as an [`Inpainter`].
pub struct DiffusionInpainter {
    model: Mutex<Box<dyn X0Model>>,
    schedule: Schedule,
    sampler: SamplerOptions,
    device: Device,
    /// Views per forward pass; short batches are padded to it.
    batch: usize,
    /// The classical fill a chain with a start step starts from.
    start: Start,
}

impl DiffusionInpainter {
    pub fn load(config: &DiffusionInpaintConfig, device: Device) -> Result<Self> {
        let model = load_model(config.checkpoint.as_path(), device)?;
        Ok(Self::from_model(model, config.sampler(), device).with_batch(config.batch).with_start(config.start))
    }

    /// Wraps a network whose variables live in `vs`.
    pub fn new(vs: nn::VarStore, net: Denoiser, sampler: SamplerOptions) -> Self {
        let device = vs.device();
        Self::from_model(Box::new(NativeModel::new(vs, net)), sampler, device)
    }

    /// Wraps any x0 predictor on `device`.
    pub fn from_model(model: Box<dyn X0Model>, sampler: SamplerOptions, device: Device) -> Self {
        DiffusionInpainter { model: Mutex::new(model), schedule: Schedule::official(), sampler, device, batch: 1, start: Start::PushPull }
    }

    /// Starts a chain with a start step from `start`'s classical fill (push–pull unless told; `noise`
    /// leaves it at push–pull, which only a start step uses).
    pub fn with_start(mut self, start: Start) -> Self {
        if start != Start::Noise {
            self.start = start;
        }
        self
    }

    /// Runs every forward pass with `batch` views.
    pub fn with_batch(mut self, batch: usize) -> Self {
        self.batch = batch.max(1);
        self
    }

    /// Samples same-sized views together (one forward pass per step for all of them).
    fn sample(&self, views: &[(&DepthMap, &[bool], &InpaintContext)]) -> Vec<DepthMap> {
        let Some((first, _, _)) = views.first() else { return Vec::new() };
        let (w, h) = (first.width() as usize, first.height() as usize);
        let ys: Vec<Vec<f32>> = views
            .iter()
            .map(|(d, known, _)| d.data().iter().zip(known.iter()).map(|(z, k)| if *k { to_network(*z) } else { -1.0 }).collect())
            .collect();
        // A known pixel without a usable depth (none, or beyond 10 m) is not imposed during sampling; the
        // output still copies it from the input, as every inpainter does with known pixels.
        let masks: Vec<Vec<bool>> = views
            .iter()
            .map(|(d, known, _)| d.data().iter().zip(known.iter()).map(|(z, k)| *k && to_network(*z) > -1.0).collect())
            .collect();
        // The classical fill a start step noises (in network space).
        let classical = self.start.classical_fill();
        let inits: Vec<Vec<f32>> = match self.sampler.start_step {
            None => Vec::new(),
            Some(_) => views
                .iter()
                .map(|(d, known, ctx)| classical.inpaint(d, known, ctx).data().iter().map(|z| to_network(*z)).collect())
                .collect(),
        };
        let problems: Vec<Problem<'_>> = views
            .iter()
            .zip(ys.iter().zip(&masks))
            .enumerate()
            .map(|(i, ((_, _, ctx), (y, m)))| Problem {
                y,
                known: m,
                intrinsics: ctx.intrinsics.as_vector(),
                seed: ctx.seed,
                init: inits.get(i).map(Vec::as_slice),
            })
            .collect();
        let out = {
            let guard = self.model.lock().unwrap_or_else(|e| e.into_inner());
            ddnm_sample(guard.as_ref(), &self.schedule, &self.sampler, w, h, &problems, self.device)
        };
        views
            .iter()
            .zip(out)
            .map(|((d, known, _), x0)| {
                // Known pixels are copied in metres (the sampler kept them exactly in network space; the
                // copy avoids the float round trip through [−1, 1]).
                let data = x0
                    .iter()
                    .zip(d.data().iter().zip(known.iter()))
                    .map(|(v, (z, k))| if *k { *z } else { from_network(*v) })
                    .collect();
                DepthMap::new(w as u32, h as u32, data).expect("same size")
            })
            .collect()
    }
}

impl Inpainter for DiffusionInpainter {
    fn name(&self) -> &'static str {
        "diffusion"
    }

    /// Runs with one libtorch intra-op thread (the pipeline runs one inpainter call per worker thread).
    fn inpaint(&self, depth: &DepthMap, known: &[bool], ctx: &InpaintContext) -> DepthMap {
        self.inpaint_batch(&[(depth, known, ctx)]).pop().expect("one view")
    }

    fn batch(&self) -> usize {
        self.batch
    }

    /// Groups of `batch` views; a short group is padded with copies of its first view (their results are
    /// dropped), so every forward pass has the same batch size and a view's result is the same whichever
    /// views it is grouped with.
    fn inpaint_batch(&self, views: &[(&DepthMap, &[bool], &InpaintContext)]) -> Vec<DepthMap> {
        tch::set_num_threads(1);
        views
            .chunks(self.batch)
            .flat_map(|group| {
                let mut padded = group.to_vec();
                padded.resize(self.batch, group[0]);
                let mut out = self.sample(&padded);
                out.truncate(group.len());
                out
            })
            .collect()
    }
}
