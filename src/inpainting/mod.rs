//! Inpainting: fill the pixels the re-projection left unknown, keeping known pixels bit-exact.

pub mod push_pull;

use crate::geometry::DepthMap;
use serde::{Deserialize, Serialize};

pub use push_pull::PushPull;

/// A depth inpainting method.
pub trait Inpainter: Send + Sync {
    /// Short name recorded in provenance.
    fn name(&self) -> &'static str;
    /// A full depth map whose known pixels equal `depth` bit for bit and whose unknown pixels are filled
    /// (or left 0 where the method cannot fill).
    fn inpaint(&self, depth: &DepthMap, known: &[bool]) -> DepthMap;
}

/// Leaves unknown pixels empty.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoInpainting;

impl Inpainter for NoInpainting {
    fn name(&self) -> &'static str {
        "none"
    }
    fn inpaint(&self, depth: &DepthMap, known: &[bool]) -> DepthMap {
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
}

impl InpaintConfig {
    /// The inpainter this config describes.
    pub fn build(&self) -> Box<dyn Inpainter> {
        match self {
            InpaintConfig::None => Box::new(NoInpainting),
            InpaintConfig::PushPull => Box::new(PushPull),
        }
    }
}
