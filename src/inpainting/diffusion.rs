//! The diffusion inpainter: the trained denoiser sampled with DDIM and the range–null-space step
//! ([`crate::diffusion::sampler`]), so the known pixels of the output are the input's.

use super::{InpaintContext, Inpainter};
use crate::diffusion::data::{from_network, to_network};
use crate::diffusion::sampler::{ddnm_sample, Problem, SamplerOptions};
use crate::diffusion::schedule::Schedule;
use crate::diffusion::checkpoint::load_denoiser;
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
    /// safetensors), relative to the working directory.
    pub checkpoint: ModelPath,
    /// DDIM steps (paper 250).
    pub steps: usize,
    /// DDIM η (official 1.0).
    #[serde(default = "official_eta")]
    pub eta: f64,
}

fn official_eta() -> f64 {
    SamplerOptions::OFFICIAL.eta
}

impl DiffusionInpaintConfig {
    pub fn validate(&self, field: &str) -> Result<()> {
        if self.steps == 0 || self.steps > 1000 {
            return Err(Error::config(field, "steps must be in 1..=1000"));
        }
        if !(self.eta >= 0.0 && self.eta <= 1.0) {
            return Err(Error::config(field, "eta must be in [0, 1]"));
        }
        crate::diffusion::checkpoint::read_meta(self.checkpoint.as_path())
            .map_err(|e| Error::config(field, format!("checkpoint `{}`: {e}", self.checkpoint)))?;
        Ok(())
    }

    pub fn sampler(&self) -> SamplerOptions {
        SamplerOptions { steps: self.steps, eta: self.eta }
    }
}

struct Loaded {
    _vs: nn::VarStore,
    net: Denoiser,
}

/// A loaded denoiser as an [`Inpainter`].
pub struct DiffusionInpainter {
    loaded: Mutex<Loaded>,
    schedule: Schedule,
    sampler: SamplerOptions,
    device: Device,
}

impl DiffusionInpainter {
    pub fn load(config: &DiffusionInpaintConfig, device: Device) -> Result<Self> {
        let (vs, net, _) = load_denoiser(config.checkpoint.as_path(), device)?;
        Ok(Self::new(vs, net, config.sampler()))
    }

    /// Wraps a network whose variables live in `vs`.
    pub fn new(vs: nn::VarStore, net: Denoiser, sampler: SamplerOptions) -> Self {
        let device = vs.device();
        DiffusionInpainter { loaded: Mutex::new(Loaded { _vs: vs, net }), schedule: Schedule::official(), sampler, device }
    }

    /// Inpaints several same-sized views in one batch (one forward pass per step for all of them).
    pub fn inpaint_batch(&self, views: &[(&DepthMap, &[bool], &InpaintContext)]) -> Vec<DepthMap> {
        let Some((first, _, _)) = views.first() else { return Vec::new() };
        let (w, h) = (first.width() as usize, first.height() as usize);
        let ys: Vec<Vec<f32>> = views
            .iter()
            .map(|(d, known, _)| d.data().iter().zip(known.iter()).map(|(z, k)| if *k { to_network(*z) } else { -1.0 }).collect())
            .collect();
        // A known pixel without a usable depth (none, or beyond 10 m) is left for the model to fill.
        let masks: Vec<Vec<bool>> = views
            .iter()
            .map(|(d, known, _)| d.data().iter().zip(known.iter()).map(|(z, k)| *k && to_network(*z) > -1.0).collect())
            .collect();
        let problems: Vec<Problem<'_>> = views
            .iter()
            .zip(ys.iter().zip(&masks))
            .map(|((_, _, ctx), (y, m))| Problem { y, known: m, intrinsics: ctx.intrinsics.as_vector(), seed: ctx.seed })
            .collect();
        let out = {
            let guard = self.loaded.lock().unwrap_or_else(|e| e.into_inner());
            ddnm_sample(&guard.net, &self.schedule, &self.sampler, w, h, &problems, self.device)
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
        tch::set_num_threads(1);
        self.inpaint_batch(&[(depth, known, ctx)]).pop().expect("one view")
    }
}
