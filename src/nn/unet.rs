//! The U-Net skeleton shared by the depth-correction network (reference §4.1, `MaskUnet`) and the
//! diffusion denoiser (§5.1, `Unet`): config, presets, module and forward.

use super::attention::{HeadShape, PreNormResidual};
use super::resnet::ResnetBlock;
use serde::{Deserialize, Serialize};
use tch::{nn, nn::Module, Tensor};

/// Hyperparameters of the U-Net.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UnetConfig {
    /// Width of `init_conv` and of the first level (official 64).
    pub dim: i64,
    /// Width multiplier per level (official 1, 2, 4, 8): level widths `dim · m`.
    pub dim_mults: Vec<i64>,
    /// Input channels (correction: 3 with DepthAugment, 1 without; diffusion: 1).
    pub in_channels: i64,
    /// Output channels of `final_conv` (1).
    pub out_channels: i64,
    /// GroupNorm groups of every block (official 8; every width must be a multiple).
    pub resnet_groups: i64,
    /// Width of the FiLM conditioning embedding given to every ResnetBlock (diffusion: 512 = time ⊕
    /// intrinsics embeddings; correction: none).
    pub cond_dim: Option<i64>,
    /// Linear attention at every level and full attention in the middle (official: on).
    pub attention: bool,
    /// Heads and width per head of the attention layers (official 4 × 32).
    #[serde(default = "official_heads")]
    pub attn_heads: i64,
    #[serde(default = "official_dim_head")]
    pub attn_dim_head: i64,
    /// `final_conv` sits inside a `Sequential(conv, Sigmoid)` in the official MaskUnet, so its key is
    /// `final_conv.0.*`; the diffusion U-Net's is `final_conv.*`.
    pub final_conv_in_sequential: bool,
}

fn official_heads() -> i64 {
    HeadShape::OFFICIAL.heads
}
fn official_dim_head() -> i64 {
    HeadShape::OFFICIAL.dim_head
}

/// Named model sizes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Preset {
    /// The paper's network: dim 64, mults 1, 2, 4, 8 (≈ 34.1 M parameters for correction).
    Paper,
    /// A CPU-trainable network: the same levels and blocks at dim 8 (mults 1, 2, 4, 8), without the
    /// attention layers (≈ 0.52 M parameters, 2 MB). Attention cost twice the convolutions at this width.
    Tiny,
}

impl Preset {
    pub fn as_str(self) -> &'static str {
        match self {
            Preset::Paper => "paper",
            Preset::Tiny => "tiny",
        }
    }

    /// `(dim, dim_mults, attention heads)` of this preset (the tiny preset has no attention layers).
    pub fn widths(self) -> (i64, Vec<i64>, HeadShape) {
        match self {
            Preset::Paper => (64, vec![1, 2, 4, 8], HeadShape::OFFICIAL),
            Preset::Tiny => (8, vec![1, 2, 4, 8], HeadShape::OFFICIAL),
        }
    }

    /// The correction network's U-Net (3 input channels with DepthAugment, 1 without).
    pub fn correction_unet(self, augment: bool) -> UnetConfig {
        let (dim, dim_mults, h) = self.widths();
        UnetConfig {
            dim,
            dim_mults,
            in_channels: if augment { 3 } else { 1 },
            out_channels: 1,
            resnet_groups: 8,
            cond_dim: None,
            attention: self == Preset::Paper,
            attn_heads: h.heads,
            attn_dim_head: h.dim_head,
            final_conv_in_sequential: true,
        }
    }

    /// The diffusion denoiser's U-Net: 1 input channel, FiLM from the 512-wide time ⊕ intrinsics embedding.
    pub fn diffusion_unet(self) -> UnetConfig {
        let (dim, dim_mults, h) = self.widths();
        UnetConfig {
            dim,
            dim_mults,
            in_channels: 1,
            out_channels: 1,
            resnet_groups: 8,
            cond_dim: Some(8 * dim),
            attention: self == Preset::Paper,
            attn_heads: h.heads,
            attn_dim_head: h.dim_head,
            final_conv_in_sequential: false,
        }
    }
}

impl UnetConfig {
    /// Channel widths `[dim, dim·m₀, dim·m₁, ...]`.
    pub fn dims(&self) -> Vec<i64> {
        std::iter::once(self.dim).chain(self.dim_mults.iter().map(|m| self.dim * m)).collect()
    }

    /// The attention layers' heads.
    pub fn head_shape(&self) -> HeadShape {
        HeadShape { heads: self.attn_heads, dim_head: self.attn_dim_head }
    }

    /// Inputs must have a height and width divisible by this (one halving per level but the last).
    pub fn size_multiple(&self) -> i64 {
        1 << (self.dim_mults.len().saturating_sub(1))
    }

    /// Checks the widths; `field` names the config in errors.
    pub fn validate(&self, field: &str) -> crate::Result<()> {
        let bad = |m: String| Err(crate::Error::config(field, m));
        if self.dim < 1
            || self.dim_mults.is_empty()
            || self.dim_mults.len() > 8
            || self.dim_mults.iter().any(|m| *m < 1)
        {
            return bad(format!("dim {} and dim_mults {:?} must be positive, 1..=8 levels", self.dim, self.dim_mults));
        }
        if self.in_channels < 1
            || self.out_channels < 1
            || self.resnet_groups < 1
            || self.attn_heads < 1
            || self.attn_dim_head < 1
        {
            return bad("channels and groups must be positive".into());
        }
        if let Some(w) = self.dims().into_iter().find(|w| w % self.resnet_groups != 0) {
            return bad(format!("width {w} is not a multiple of resnet_groups {}", self.resnet_groups));
        }
        Ok(())
    }
}

/// One encoder level: `downs.{i}.{0,1}` ResnetBlocks, `downs.{i}.2` linear attention, `downs.{i}.3`
/// the downsampling conv (4×4 stride 2, or 3×3 at the last level).
#[derive(Debug)]
struct Down {
    block1: ResnetBlock,
    block2: ResnetBlock,
    attn: Option<PreNormResidual>,
    down: nn::Conv2D,
}

/// One decoder level: `ups.{i}.{0,1}` ResnetBlocks over the concatenated skips, `ups.{i}.2` linear
/// attention, `ups.{i}.3.1` nearest ×2 then 3×3 conv (or `ups.{i}.3` without upsampling at the last level).
#[derive(Debug)]
struct Up {
    block1: ResnetBlock,
    block2: ResnetBlock,
    attn: Option<PreNormResidual>,
    up: nn::Conv2D,
    upsample: bool,
}

/// The U-Net (see the module docs; topology of reference §4.1).
#[derive(Debug)]
pub struct Unet {
    pub config: UnetConfig,
    init_conv: nn::Conv2D,
    downs: Vec<Down>,
    mid_block1: ResnetBlock,
    mid_attn: Option<PreNormResidual>,
    mid_block2: ResnetBlock,
    ups: Vec<Up>,
    final_res_block: ResnetBlock,
    final_conv: nn::Conv2D,
}

fn conv(p: nn::Path, c_in: i64, c_out: i64, k: i64, stride: i64, padding: i64) -> nn::Conv2D {
    super::init::conv(p, c_in, c_out, k, stride, padding, true)
}

impl Unet {
    /// Creates the variables under `p` (call [`UnetConfig::validate`] first).
    pub fn new(p: &nn::Path, config: &UnetConfig) -> Self {
        let c = config;
        let (g, cd, hs) = (c.resnet_groups, c.cond_dim, c.head_shape());
        let dims = c.dims();
        let pairs: Vec<(i64, i64)> = dims.windows(2).map(|w| (w[0], w[1])).collect();
        let levels = pairs.len();
        let init_conv = conv(p / "init_conv", c.in_channels, c.dim, 7, 1, 3);
        let downs = pairs
            .iter()
            .enumerate()
            .map(|(i, &(cin, cout))| {
                let q = p / "downs" / i;
                let last = i + 1 == levels;
                Down {
                    block1: ResnetBlock::new(&(&q / 0), cin, cin, g, cd),
                    block2: ResnetBlock::new(&(&q / 1), cin, cin, g, cd),
                    attn: c.attention.then(|| PreNormResidual::new(&(&q / 2), cin, false, hs)),
                    down: if last { conv(&q / 3, cin, cout, 3, 1, 1) } else { conv(&q / 3, cin, cout, 4, 2, 1) },
                }
            })
            .collect();
        let mid = *dims.last().expect("at least one level");
        let ups = pairs
            .iter()
            .rev()
            .enumerate()
            .map(|(i, &(cin, cout))| {
                let q = p / "ups" / i;
                let last = i + 1 == levels;
                Up {
                    block1: ResnetBlock::new(&(&q / 0), cout + cin, cout, g, cd),
                    block2: ResnetBlock::new(&(&q / 1), cout + cin, cout, g, cd),
                    attn: c.attention.then(|| PreNormResidual::new(&(&q / 2), cout, false, hs)),
                    up: if last { conv(&q / 3, cout, cin, 3, 1, 1) } else { conv(&q / 3 / 1, cout, cin, 3, 1, 1) },
                    upsample: !last,
                }
            })
            .collect();
        let final_path = if c.final_conv_in_sequential { p / "final_conv" / 0 } else { p / "final_conv" };
        Unet {
            config: c.clone(),
            init_conv,
            downs,
            mid_block1: ResnetBlock::new(&(p / "mid_block1"), mid, mid, g, cd),
            mid_attn: c.attention.then(|| PreNormResidual::new(&(p / "mid_attn"), mid, true, hs)),
            mid_block2: ResnetBlock::new(&(p / "mid_block2"), mid, mid, g, cd),
            ups,
            final_res_block: ResnetBlock::new(&(p / "final_res_block"), 2 * c.dim, c.dim, g, cd),
            final_conv: conv(final_path, c.dim, c.out_channels, 1, 1, 0),
        }
    }

    /// Shapes: `x [B, in_channels, H, W]` with H, W multiples of [`UnetConfig::size_multiple`],
    /// `cond [B, cond_dim]` iff conditioned → `[B, out_channels, H, W]` (no output activation).
    pub fn forward(&self, x: &Tensor, cond: Option<&Tensor>) -> Tensor {
        let mut x = self.init_conv.forward(x);
        let r = x.shallow_clone();
        let mut skips = Vec::with_capacity(2 * self.downs.len());
        for d in &self.downs {
            x = d.block1.forward(&x, cond);
            skips.push(x.shallow_clone());
            x = d.block2.forward(&x, cond);
            if let Some(a) = &d.attn {
                x = a.forward(&x);
            }
            skips.push(x.shallow_clone());
            x = d.down.forward(&x);
        }
        x = self.mid_block1.forward(&x, cond);
        if let Some(a) = &self.mid_attn {
            x = a.forward(&x);
        }
        x = self.mid_block2.forward(&x, cond);
        for u in &self.ups {
            x = u.block1.forward(&Tensor::cat(&[&x, &skips.pop().expect("skip")], 1), cond);
            x = u.block2.forward(&Tensor::cat(&[&x, &skips.pop().expect("skip")], 1), cond);
            if let Some(a) = &u.attn {
                x = a.forward(&x);
            }
            if u.upsample {
                let (_, _, h, w) = x.size4().expect("[B, C, H, W]");
                x = x.upsample_nearest2d([2 * h, 2 * w], None, None);
            }
            x = u.up.forward(&x);
        }
        x = self.final_res_block.forward(&Tensor::cat(&[&x, &r], 1), cond);
        self.final_conv.forward(&x)
    }
}

/// Number of scalar parameters in a variable store.
pub fn parameter_count(vs: &nn::VarStore) -> i64 {
    vs.variables().values().map(|t| t.numel() as i64).sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, Kind};

    #[test]
    fn a_small_unet_keeps_the_spatial_size_and_names_the_official_keys() {
        let cfg = UnetConfig {
            dim: 8,
            dim_mults: vec![1, 2],
            in_channels: 3,
            out_channels: 1,
            resnet_groups: 4,
            cond_dim: Some(6),
            attention: true,
            attn_heads: 2,
            attn_dim_head: 4,
            final_conv_in_sequential: true,
        };
        cfg.validate("unet").unwrap();
        let vs = nn::VarStore::new(Device::Cpu);
        let net = Unet::new(&vs.root(), &cfg);
        let y = net.forward(
            &Tensor::randn([2, 3, 8, 12], (Kind::Float, Device::Cpu)),
            Some(&Tensor::randn([2, 6], (Kind::Float, Device::Cpu))),
        );
        assert_eq!(y.size(), vec![2, 1, 8, 12]);
        let names: std::collections::BTreeSet<String> = vs.variables().into_keys().collect();
        for k in [
            "init_conv.weight",
            "downs.0.0.block1.proj.weight",
            "downs.0.0.mlp.1.weight",
            "downs.0.2.fn.fn.to_qkv.weight",
            "downs.0.2.fn.fn.to_out.1.g",
            "downs.0.2.fn.norm.g",
            "downs.0.3.weight",
            "downs.1.3.bias",
            "mid_attn.fn.fn.to_out.weight",
            "mid_attn.fn.norm.g",
            "mid_block2.block2.norm.bias",
            "ups.0.0.res_conv.weight",
            "ups.0.3.1.weight",
            "ups.1.3.weight",
            "final_res_block.res_conv.weight",
            "final_conv.0.weight",
        ] {
            assert!(names.contains(k), "missing {k}: {names:?}");
        }
        assert!(!names.contains("downs.0.0.res_conv.weight"));
    }

    #[test]
    fn widths_not_divisible_by_the_groups_are_refused() {
        let mut cfg = Preset::Tiny.correction_unet(true);
        cfg.resnet_groups = 3;
        assert!(cfg.validate("unet").unwrap_err().to_string().contains("multiple"));
    }
}
