//! The trained correction U-Net as a [`Corrector`] (reference §4): keeps a pixel when the network's keep
//! probability exceeds τ_m.

use super::Corrector;
use crate::error::Result;
use crate::geometry::DepthMap;
use crate::nn::correction::{keep_probabilities, CorrectionNet, CorrectionNetConfig};
use crate::nn::space::normalise_depth;
use std::sync::Mutex;
use tch::{nn, Device};

struct Loaded {
    _vs: nn::VarStore,
    net: CorrectionNet,
}

/// A trained [`CorrectionNet`] as a [`Corrector`]: keeps a pixel when its keep probability exceeds
/// `threshold` (τ_m; official 0.99) or when it has no depth.
pub struct UnetCorrector {
    loaded: Mutex<Loaded>,
    threshold: f32,
    device: Device,
}

impl UnetCorrector {
    /// Wraps a network whose variables live in `vs`.
    pub fn new(vs: nn::VarStore, net: CorrectionNet, threshold: f32) -> Self {
        let device = vs.device();
        UnetCorrector { loaded: Mutex::new(Loaded { _vs: vs, net }), threshold, device }
    }

    /// Loads a checkpoint (see [`crate::nn::checkpoint::load_correction`]) onto `device`.
    pub fn load(path: &std::path::Path, threshold: f32, device: Device) -> Result<Self> {
        let (vs, net, _) = crate::nn::checkpoint::load_correction(path, device)?;
        Ok(UnetCorrector::new(vs, net, threshold))
    }

    pub fn threshold(&self) -> f32 {
        self.threshold
    }

    /// The network's configuration.
    pub fn config(&self) -> CorrectionNetConfig {
        self.lock().net.config.clone()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Loaded> {
        self.loaded.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Keep probability of every pixel of same-sized depth maps (metres), batched by `batch`.
    pub fn probabilities(&self, maps: &[&DepthMap], batch: usize) -> Vec<Vec<f32>> {
        let Some(first) = maps.first() else { return Vec::new() };
        let (w, h) = (first.width() as usize, first.height() as usize);
        let inputs: Vec<Vec<f32>> =
            maps.iter().map(|d| d.data().iter().map(|z| normalise_depth(*z)).collect()).collect();
        let refs: Vec<&[f32]> = inputs.iter().map(Vec::as_slice).collect();
        keep_probabilities(&self.lock().net, self.device, w, h, &refs, batch)
    }
}

impl Corrector for UnetCorrector {
    fn name(&self) -> &'static str {
        "unet"
    }

    /// Runs with one libtorch intra-op thread (set on the calling thread): the pipeline already runs one
    /// corrector per worker thread, and more threads than cores make libtorch's workers spin.
    fn keep_mask(&self, depth: &DepthMap) -> Vec<bool> {
        tch::set_num_threads(1);
        let p = self.probabilities(&[depth], 1).pop().expect("one map");
        depth.data().iter().zip(p).map(|(z, p)| normalise_depth(*z) == 0.0 || p > self.threshold).collect()
    }
}
