//! The depth-correction network (reference §4.1 `MaskUnet`): DepthAugment → U-Net → sigmoid keep
//! probability, and its inference wrapper implementing [`crate::correction::Corrector`].

use super::augment::depth_augment;
use super::unet::{Preset, Unet, UnetConfig};
use crate::correction::Corrector;
use crate::error::{Error, Result};
use crate::geometry::DepthMap;
use serde::{Deserialize, Serialize};
use std::sync::Mutex;
use tch::{nn, Device, Kind, Tensor};

/// Metres per unit of the network's depth input (1.0 = 10 m; deeper is treated as missing).
pub const DEPTH_SCALE_M: f32 = 10.0;

/// Hyperparameters of a [`CorrectionNet`].
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CorrectionNetConfig {
    /// The preset the U-Net was made from (None: custom widths, e.g. an inferred official checkpoint).
    pub preset: Option<Preset>,
    /// DepthAugment's three input channels (official: on); off feeds the depth alone.
    pub augment: bool,
    pub unet: UnetConfig,
}

impl CorrectionNetConfig {
    pub fn from_preset(preset: Preset, augment: bool) -> Self {
        CorrectionNetConfig { preset: Some(preset), augment, unet: preset.correction_unet(augment) }
    }

    pub fn validate(&self) -> Result<()> {
        self.unet.validate("correction.unet")?;
        let want = if self.augment { 3 } else { 1 };
        if self.unet.in_channels != want || self.unet.out_channels != 1 || self.unet.cond_dim.is_some() {
            return Err(Error::config(
                "correction.unet",
                format!(
                    "a correction U-Net has {want} input channel(s) (augment {}), 1 output and no conditioning",
                    self.augment
                ),
            ));
        }
        Ok(())
    }
}

/// `forward(depth) → keep probability`.
#[derive(Debug)]
pub struct CorrectionNet {
    pub config: CorrectionNetConfig,
    pub unet: Unet,
}

impl CorrectionNet {
    /// Creates the variables under `p` (the official keys sit at the root).
    pub fn new(p: &nn::Path, config: &CorrectionNetConfig) -> Result<Self> {
        config.validate()?;
        Ok(CorrectionNet { config: config.clone(), unet: Unet::new(p, &config.unet) })
    }

    /// Shapes: `depth [B, 1, H, W]` in [0, 1] (metres / 10, 0 = missing), H and W multiples of
    /// [`UnetConfig::size_multiple`] → logits `[B, 1, H, W]`.
    pub fn forward_logits(&self, depth: &Tensor) -> Tensor {
        if self.config.augment {
            self.unet.forward(&depth_augment(depth), None)
        } else {
            self.unet.forward(depth, None)
        }
    }

    /// Shapes: `depth [B, 1, H, W]` as in [`Self::forward_logits`] → keep probability `[B, 1, H, W]`.
    pub fn forward(&self, depth: &Tensor) -> Tensor {
        self.forward_logits(depth).sigmoid()
    }
}

/// The network's input value of a metric depth: `z / 10`, with missing, non-finite and > 10 m as 0.
pub fn normalise_depth(z: f32) -> f32 {
    let v = z / DEPTH_SCALE_M;
    if v.is_finite() && v > 0.0 && v <= 1.0 {
        v
    } else {
        0.0
    }
}

/// Keep probabilities of same-sized normalised depth maps (`[0, 1]` values, row-major), in batches of
/// `batch`, padding H and W with missing depth up to the U-Net's size multiple.
pub fn keep_probabilities(
    net: &CorrectionNet,
    device: Device,
    width: usize,
    height: usize,
    maps: &[&[f32]],
    batch: usize,
) -> Vec<Vec<f32>> {
    let m = net.config.unet.size_multiple() as usize;
    let (pw, ph) = (width.div_ceil(m) * m, height.div_ceil(m) * m);
    let mut out = Vec::with_capacity(maps.len());
    tch::no_grad(|| {
        for chunk in maps.chunks(batch.max(1)) {
            let mut buf = vec![0f32; chunk.len() * pw * ph];
            for (b, map) in chunk.iter().enumerate() {
                assert_eq!(map.len(), width * height, "maps of one call share a size");
                for r in 0..height {
                    buf[b * pw * ph + r * pw..b * pw * ph + r * pw + width]
                        .copy_from_slice(&map[r * width..(r + 1) * width]);
                }
            }
            let x = Tensor::from_slice(&buf).view([chunk.len() as i64, 1, ph as i64, pw as i64]).to_device(device);
            let p = net.forward(&x).to_device(Device::Cpu).to_kind(Kind::Float).contiguous();
            let p: Vec<f32> = Vec::try_from(p.flatten(0, -1)).expect("float probabilities");
            for b in 0..chunk.len() {
                let mut v = Vec::with_capacity(width * height);
                for r in 0..height {
                    v.extend_from_slice(&p[b * pw * ph + r * pw..b * pw * ph + r * pw + width]);
                }
                out.push(v);
            }
        }
    });
    out
}

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

    /// Loads a checkpoint (see [`super::checkpoint::load_correction`]) onto `device`.
    pub fn load(path: &std::path::Path, threshold: f32, device: Device) -> Result<Self> {
        let (vs, net, _) = super::checkpoint::load_correction(path, device)?;
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
