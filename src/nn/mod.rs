//! Neural networks on libtorch (tch), inference side: the shared U-Net skeleton, the depth-correction
//! network, the diffusion denoiser, their checkpoints and the network-space depth mapping. The sampler
//! lives in [`crate::diffusion`], the build's corrector in [`crate::correction::unet`], training and
//! evaluation in [`crate::training`] (which depends on this module, never the other way).
//!
//! Layout (one layer per file):
//! - layers: [`ws_conv`] (weight-standardised conv), [`norm`] (channel LayerNorm), [`resnet`] (Block and
//!   ResnetBlock with optional FiLM), [`attention`] (linear and full attention, pre-norm residual);
//! - models: [`unet`] (the skeleton of reference §4.1 / §5.1 with its presets), [`augment`]
//!   (DepthAugment), [`correction`] (`CorrectionNet`), [`denoiser`] (the diffusion U-Net with time and
//!   intrinsics FiLM conditioning), the learned registration descriptors: [`patch_net`] (a 3D ConvNet on
//!   distance-field patches) and [`fpfh_mlp`] (an MLP on multi-scale FPFH);
//! - [`space`]: metric depth ↔ network values (`z/10`, `2·z/10 − 1`), the one place for those formulas;
//! - I/O: [`checkpoint`] (safetensors with the config in the header metadata; the authors' key layout),
//!   [`model_path`], [`shipped`] (the default checkpoints built into the binary, `builtin:models/…`).
//!
//! Variable names follow the authors' PyTorch state-dict keys (`init_conv.weight`,
//! `downs.0.0.block1.proj.weight`, ..., `final_conv.0.weight`), so a converted `model-best.pt` loads
//! without renaming.

pub mod attention;
pub mod augment;
pub mod checkpoint;
pub mod correction;
pub mod denoiser;
pub mod fpfh_mlp;
pub mod init;
pub mod model_path;
pub mod norm;
pub mod patch_net;
pub mod resnet;
pub mod shipped;
pub mod space;
pub mod unet;
pub mod ws_conv;

pub use augment::depth_augment;
pub use checkpoint::{load_correction, save_correction, CheckpointMeta};
pub use correction::{CorrectionNet, CorrectionNetConfig};
pub use model_path::ModelPath;
pub use unet::{Preset, Unet, UnetConfig};

/// Each row of `x` (`[B, D]`) divided by its length: unit descriptors.
pub fn unit_rows(x: &tch::Tensor) -> tch::Tensor {
    x / x.norm_scalaropt_dim(2.0, [1i64], true).clamp_min(1e-8)
}

/// Sets libtorch's intra-op threads for this process (`--torch-threads`, at least 1).
pub fn set_torch_threads(n: i32) -> crate::Result<()> {
    if n < 1 {
        return Err(crate::Error::config("--torch-threads", "must be at least 1"));
    }
    tch::set_num_threads(n);
    Ok(())
}

/// Parses a device name: `cpu`, `cuda` (the first GPU) or `cuda:N`.
pub fn parse_device(name: &str) -> crate::Result<tch::Device> {
    match name {
        "cpu" => Ok(tch::Device::Cpu),
        "cuda" => cuda(0),
        s => match s.strip_prefix("cuda:").and_then(|n| n.parse::<usize>().ok()) {
            Some(n) => cuda(n),
            None => Err(crate::Error::config("--device", format!("unknown device `{s}` (cpu, cuda, cuda:N)"))),
        },
    }
}

fn cuda(n: usize) -> crate::Result<tch::Device> {
    if tch::Cuda::device_count() as usize > n {
        Ok(tch::Device::Cuda(n))
    } else {
        Err(crate::Error::config(
            "--device",
            format!("CUDA device {n} is not available (libtorch sees {} GPUs)", tch::Cuda::device_count()),
        ))
    }
}
