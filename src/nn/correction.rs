//! The depth-correction network (reference §4.1 `MaskUnet`): DepthAugment → U-Net → sigmoid keep
//! probability. The build's corrector around it is `crate::correction::UnetCorrector`.

use super::augment::depth_augment;
use super::unet::{Preset, Unet, UnetConfig};
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use tch::{nn, Device, Kind, Tensor};

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
