//! Inpainting: fill the pixels the re-projection left unknown, keeping known pixels bit-exact. Methods:
//! none, the classical push–pull fill ([`push_pull`]) and the diffusion model with the range–null-space
//! step ([`diffusion`]); [`config`] names them in pipeline configs.

pub mod config;
pub mod diffusion;
pub mod push_pull;

use crate::geometry::{DepthMap, Intrinsics};

pub use config::InpaintConfig;
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

/// A context for unit tests of inpainters: a pinhole camera centred on the map, seed 0.
#[cfg(test)]
pub(crate) fn test_context(d: &DepthMap) -> InpaintContext {
    let (w, h) = (d.width(), d.height());
    InpaintContext { intrinsics: Intrinsics::new(w as f64, w as f64, w as f64 / 2.0, h as f64 / 2.0, w, h).unwrap(), seed: 0 }
}
