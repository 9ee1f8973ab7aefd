//! Inpainting: fill the pixels the re-projection left unknown, keeping known pixels bit-exact.

pub mod diffusion;
pub mod push_pull;

use crate::geometry::{DepthMap, Intrinsics};
use serde::{Deserialize, Serialize};

pub use diffusion::{DiffusionInpaintConfig, DiffusionInpainter, Start};
pub use push_pull::PushPull;

/// What an inpainter may know about a target view besides its pixels.
#[derive(Clone, Copy, Debug)]
pub struct InpaintContext {
    /// The target camera's working-resolution intrinsics.
    pub intrinsics: Intrinsics,
    /// The work unit's seed: every random draw of a stochastic method comes from it.
    pub seed: u64,
}

/// A depth inpainting method.
pub trait Inpainter: Send + Sync {
    /// Short name recorded in provenance.
    fn name(&self) -> &'static str;
    /// A full depth map whose known pixels equal `depth` bit for bit and whose unknown pixels are filled
    /// (or left 0 where the method cannot fill).
    fn inpaint(&self, depth: &DepthMap, known: &[bool], ctx: &InpaintContext) -> DepthMap;
    /// How many views [`Inpainter::inpaint_batch`] fills together at best (1: one at a time).
    fn batch(&self) -> usize {
        1
    }
    /// Fills several views; each result is what [`Inpainter::inpaint`] gives for that view alone.
    fn inpaint_batch(&self, views: &[(&DepthMap, &[bool], &InpaintContext)]) -> Vec<DepthMap> {
        views.iter().map(|(d, known, ctx)| self.inpaint(d, known, ctx)).collect()
    }
}

/// Leaves unknown pixels empty.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoInpainting;

impl Inpainter for NoInpainting {
    fn name(&self) -> &'static str {
        "none"
    }
    fn inpaint(&self, depth: &DepthMap, known: &[bool], _: &InpaintContext) -> DepthMap {
        let mut out = depth.clone();
        for (z, k) in out.data_mut().iter_mut().zip(known) {
            if !k {
                *z = 0.0;
            }
        }
        out
    }
}

/// The inpainting methods a pipeline config can name.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "method", rename_all = "snake_case", deny_unknown_fields)]
pub enum InpaintConfig {
    /// No filling: the target keeps only the re-projected pixels.
    None,
    /// Classical push–pull pyramid fill (smooth, fast).
    PushPull,
    /// The diffusion model with the exact range–null-space step (paper §3.2, reference §5.4).
    Diffusion(DiffusionInpaintConfig),
}

impl InpaintConfig {
    /// Checks the settings (and that a diffusion checkpoint loads); `field` names the config in errors.
    pub fn validate(&self, field: &str) -> crate::Result<()> {
        match self {
            InpaintConfig::Diffusion(c) => c.validate(field),
            _ => Ok(()),
        }
    }

    /// The model file this method reads, if any.
    pub fn checkpoint(&self) -> Option<crate::nn::ModelPath> {
        match self {
            InpaintConfig::Diffusion(c) => Some(c.checkpoint),
            _ => None,
        }
    }

    /// The inpainter this config describes (call [`Self::validate`] first).
    pub fn build(&self) -> crate::Result<Box<dyn Inpainter>> {
        Ok(match self {
            InpaintConfig::None => Box::new(NoInpainting),
            InpaintConfig::PushPull => Box::new(PushPull),
            InpaintConfig::Diffusion(c) => Box::new(DiffusionInpainter::load(c, tch::Device::Cpu)?),
        })
    }
}

/// A context for unit tests of inpainters: a pinhole camera centred on the map, seed 0.
#[cfg(test)]
pub(crate) fn test_context(d: &DepthMap) -> InpaintContext {
    let (w, h) = (d.width(), d.height());
    InpaintContext { intrinsics: Intrinsics::new(w as f64, w as f64, w as f64 / 2.0, h as f64 / 2.0, w, h).unwrap(), seed: 0 }
}
