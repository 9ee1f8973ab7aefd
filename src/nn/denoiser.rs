//! The diffusion denoiser (reference §5.1): the shared [`Unet`] predicting x0 from x_t, conditioned by FiLM
//! in every ResnetBlock on the time step (sinusoidal embedding → MLP) joined with the working-resolution
//! intrinsics `[fx, fy, cx, cy]` (2-layer MLP). No image channel besides x_t: the inpainting conditioning
//! is the sampler's range–null-space step ([`crate::diffusion::sampler`]).
//!
//! Variables follow the authors' keys: `time_mlp.{1,3}.*`, `param_mlp.{0,2}.*` and the U-Net's.

use super::init::linear;
use super::unet::{Preset, Unet, UnetConfig};
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use tch::{nn, nn::Module, Kind, Tensor};

/// Hyperparameters of a [`Denoiser`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DenoiserConfig {
    /// The preset the network was made from (None: custom widths, e.g. an inferred official checkpoint).
    pub preset: Option<Preset>,
    pub unet: UnetConfig,
    /// Factor applied to `[fx, fy, cx, cy]` (pixels) before the intrinsics MLP. Official 1 (raw values,
    /// about 300 at 256²); the tiny preset uses 1/256 so a freshly initialised network does not start
    /// with FiLM scales in the hundreds.
    pub intrinsics_scale: f64,
}

impl DenoiserConfig {
    pub fn from_preset(preset: Preset) -> Self {
        let intrinsics_scale = match preset {
            Preset::Paper => 1.0,
            Preset::Tiny => 1.0 / 256.0,
        };
        DenoiserConfig { preset: Some(preset), unet: preset.diffusion_unet(), intrinsics_scale }
    }

    /// Width of the time and of the intrinsics embedding (official `4·dim` = 256); the FiLM input is both.
    pub fn embedding_dim(&self) -> i64 {
        4 * self.unet.dim
    }

    pub fn validate(&self) -> Result<()> {
        self.unet.validate("diffusion.unet")?;
        let u = &self.unet;
        if u.in_channels != 1 || u.out_channels != 1 || u.cond_dim != Some(2 * self.embedding_dim()) || u.dim < 4 {
            return Err(Error::config(
                "diffusion.unet",
                format!(
                    "a denoiser has 1 input and 1 output channel, dim >= 4 and FiLM width 8*dim = {} (got in {}, out {}, cond {:?})",
                    8 * u.dim,
                    u.in_channels,
                    u.out_channels,
                    u.cond_dim
                ),
            ));
        }
        if !(self.intrinsics_scale.is_finite() && self.intrinsics_scale > 0.0) {
            return Err(Error::config("diffusion.intrinsics_scale", "must be a positive number"));
        }
        Ok(())
    }
}

/// `SinusoidalPosEmb(dim)` of lucidrains' U-Net: `[sin(t·f_k), cos(t·f_k)]`, `f_k = exp(−k·ln(10⁴)/(dim/2 − 1))`.
/// Shapes: `t [B]` (any numeric kind) → `[B, dim]`.
pub fn sinusoidal_embedding(t: &Tensor, dim: i64) -> Tensor {
    let half = dim / 2;
    let freqs = (Tensor::arange(half, (Kind::Float, t.device())) * (-(10_000f64.ln()) / (half - 1) as f64)).exp();
    let a = t.to_kind(Kind::Float).unsqueeze(1) * freqs.unsqueeze(0);
    Tensor::cat(&[a.sin(), a.cos()], 1)
}

/// `forward(x_t, t, intrinsics) → x0` (see the module docs).
#[derive(Debug)]
pub struct Denoiser {
    pub config: DenoiserConfig,
    time_mlp1: nn::Linear,
    time_mlp3: nn::Linear,
    param_mlp0: nn::Linear,
    param_mlp2: nn::Linear,
    pub unet: Unet,
}

impl Denoiser {
    /// Creates the variables under `p` (the official keys sit at the root).
    pub fn new(p: &nn::Path, config: &DenoiserConfig) -> Result<Self> {
        config.validate()?;
        let (dim, e) = (config.unet.dim, config.embedding_dim());
        Ok(Denoiser {
            config: config.clone(),
            time_mlp1: linear(p / "time_mlp" / 1, dim, e),
            time_mlp3: linear(p / "time_mlp" / 3, e, e),
            param_mlp0: linear(p / "param_mlp" / 0, 4, e),
            param_mlp2: linear(p / "param_mlp" / 2, e, e),
            unet: Unet::new(p, &config.unet),
        })
    }

    /// Shapes: `x [B, 1, H, W]` in network space ([−1, 1], H and W multiples of
    /// [`UnetConfig::size_multiple`]), `t [B]` integer steps, `intrinsics [B, 4]` pixels → x0 `[B, 1, H, W]`.
    pub fn forward(&self, x: &Tensor, t: &Tensor, intrinsics: &Tensor) -> Tensor {
        let time = self
            .time_mlp3
            .forward(&self.time_mlp1.forward(&sinusoidal_embedding(t, self.config.unet.dim)).gelu("none"));
        let k = intrinsics.to_kind(Kind::Float) * self.config.intrinsics_scale;
        let param = self.param_mlp2.forward(&self.param_mlp0.forward(&k).gelu("none"));
        self.unet.forward(x, Some(&Tensor::cat(&[time, param], 1)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Device;

    #[test]
    fn sinusoidal_embedding_matches_the_formula() {
        let t = Tensor::from_slice(&[0i64, 7, 999]);
        let e = sinusoidal_embedding(&t, 8);
        assert_eq!(e.size(), vec![3, 8]);
        for (b, tv) in [0.0f64, 7.0, 999.0].iter().enumerate() {
            for k in 0..4 {
                let f = (-(k as f64) * 10_000f64.ln() / 3.0).exp();
                let s = e.double_value(&[b as i64, k]);
                let c = e.double_value(&[b as i64, 4 + k]);
                assert!((s - (tv * f).sin()).abs() < 1e-4 && (c - (tv * f).cos()).abs() < 1e-4, "t {tv} k {k}");
            }
        }
    }

    #[test]
    fn the_paper_preset_has_the_reference_size_and_keys() {
        let vs = nn::VarStore::new(Device::Cpu);
        let net = Denoiser::new(&vs.root(), &DenoiserConfig::from_preset(Preset::Paper)).unwrap();
        let n = super::super::unet::parameter_count(&vs);
        // Reference §5.1: about 38.4 M parameters.
        assert!((38_000_000..38_900_000).contains(&n), "{n}");
        let names: std::collections::BTreeSet<String> = vs.variables().into_keys().collect();
        for k in ["time_mlp.1.weight", "time_mlp.3.bias", "param_mlp.0.weight", "param_mlp.2.bias", "final_conv.weight"] {
            assert!(names.contains(k), "missing {k}");
        }
        assert_eq!(vs.variables()["param_mlp.0.weight"].size(), vec![256, 4]);
        assert_eq!(vs.variables()["downs.0.0.mlp.1.weight"].size(), vec![128, 512]);
        drop(net);
    }

    #[test]
    fn the_tiny_denoiser_keeps_the_shape_and_reacts_to_time_and_intrinsics() {
        tch::manual_seed(1);
        let vs = nn::VarStore::new(Device::Cpu);
        let net = Denoiser::new(&vs.root(), &DenoiserConfig::from_preset(Preset::Tiny)).unwrap();
        let x = Tensor::randn([2, 1, 32, 32], (Kind::Float, Device::Cpu));
        let k = Tensor::from_slice(&[300f32, 300.0, 128.5, 128.0, 300.0, 300.0, 128.5, 128.0]).view([2, 4]);
        let t = Tensor::from_slice(&[10i64, 10]);
        let y = tch::no_grad(|| net.forward(&x, &t, &k));
        assert_eq!(y.size(), vec![2, 1, 32, 32]);
        let y2 = tch::no_grad(|| net.forward(&x, &Tensor::from_slice(&[900i64, 900]), &k));
        assert!(f64::try_from((&y - &y2).abs().max()).unwrap() > 1e-6);
        let k2 = &k * 0.5;
        let y3 = tch::no_grad(|| net.forward(&x, &t, &k2));
        assert!(f64::try_from((&y - &y3).abs().max()).unwrap() > 1e-6);
    }
}
