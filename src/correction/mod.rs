//! Depth correction: which re-projected pixels to keep, removing points that "penetrate" a surface.
//!
//! A corrector returns a keep mask over a depth map (0 = no depth). The pipeline zeroes the pixels it
//! drops, on the re-projected condition and again on the inpainted output (reference §3.3). Methods: the
//! official min-pool filter ([`minpool`]), a median baseline ([`median`]) and the trained U-Net
//! ([`unet`]); [`config`] names them in pipeline configs.

pub mod config;
pub mod median;
pub mod minpool;
pub mod unet;

use crate::geometry::DepthMap;

pub use config::{CorrectionConfig, SceneRule};
pub use median::MedianFilter;
pub use minpool::MinPoolFilter;
pub use unet::UnetCorrector;

/// A keep-mask producer.
pub trait Corrector: Send + Sync {
    /// Short name recorded in provenance.
    fn name(&self) -> &'static str;
    /// `true` for each pixel of `depth` to keep. Pixels without depth are always kept (there is nothing
    /// to drop).
    fn keep_mask(&self, depth: &DepthMap) -> Vec<bool>;
}

/// Keeps everything.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoCorrection;

impl Corrector for NoCorrection {
    fn name(&self) -> &'static str {
        "none"
    }
    fn keep_mask(&self, depth: &DepthMap) -> Vec<bool> {
        vec![true; depth.data().len()]
    }
}

/// Zeroes the pixels of `depth` that `keep` drops and clears them from `known` too; returns how many.
pub fn apply_keep_mask(depth: &mut DepthMap, known: &mut [bool], keep: &[bool]) -> usize {
    let mut dropped = 0;
    for ((z, k), &kp) in depth.data_mut().iter_mut().zip(known.iter_mut()).zip(keep) {
        if !kp && *z > 0.0 {
            *z = 0.0;
            *k = false;
            dropped += 1;
        }
    }
    dropped
}

/// The correction label (paper §3.3): `M_gt[p] = |I_s[p] − I_d[p]| < τ_gt`, with empty pixels as 0 (the official formula): a pixel empty in
/// both is kept; a sparse depth where the dense map is empty, or more than τ_gt off, is dropped.
/// `true` = keep.
pub fn keep_label(sparse: &DepthMap, dense: &DepthMap, tau_gt: f32) -> Vec<bool> {
    assert_eq!(sparse.data().len(), dense.data().len(), "label maps differ in size");
    sparse.data().iter().zip(dense.data()).map(|(&s, &d)| (s - d).abs() < tau_gt).collect()
}
