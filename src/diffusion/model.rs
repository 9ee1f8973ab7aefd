//! What the sampler runs: any x0 predictor `(x_t, t, K) → x0` — our [`Denoiser`] from a safetensors
//! checkpoint (ours or the authors' layout), or a TorchScript module with the same signature.

use super::checkpoint::load_denoiser;
use crate::error::{Error, Result};
use crate::nn::denoiser::Denoiser;
use std::path::Path;
use tch::{nn, CModule, Device, Tensor};

/// An x0 predictor: `x [B, 1, H, W]` in network space, `t [B]` int64 steps, `intrinsics [B, 4]` pixels
/// → x0 `[B, 1, H, W]`.
pub trait X0Model: Send {
    fn predict_x0(&self, x: &Tensor, t: &Tensor, intrinsics: &Tensor) -> Tensor;
    /// Inputs are padded to multiples of this.
    fn size_multiple(&self) -> usize;
}

impl X0Model for Denoiser {
    fn predict_x0(&self, x: &Tensor, t: &Tensor, intrinsics: &Tensor) -> Tensor {
        self.forward(x, t, intrinsics)
    }
    fn size_multiple(&self) -> usize {
        self.config.unet.size_multiple() as usize
    }
}

/// A denoiser with the variable store that owns its weights.
pub struct NativeModel {
    _vs: nn::VarStore,
    pub net: Denoiser,
}

impl NativeModel {
    pub fn new(vs: nn::VarStore, net: Denoiser) -> Self {
        NativeModel { _vs: vs, net }
    }
}

impl X0Model for NativeModel {
    fn predict_x0(&self, x: &Tensor, t: &Tensor, intrinsics: &Tensor) -> Tensor {
        self.net.forward(x, t, intrinsics)
    }
    fn size_multiple(&self) -> usize {
        X0Model::size_multiple(&self.net)
    }
}

/// A TorchScript module whose `forward(x, t, intrinsics)` returns x0 (a traced or scripted export of a
/// denoiser trained elsewhere). Inputs are padded to multiples of [`TorchScriptModel::SIZE_MULTIPLE`].
pub struct TorchScriptModel {
    module: CModule,
}

impl TorchScriptModel {
    /// Enough for U-Nets of up to six levels.
    pub const SIZE_MULTIPLE: usize = 32;
}

impl X0Model for TorchScriptModel {
    fn predict_x0(&self, x: &Tensor, t: &Tensor, intrinsics: &Tensor) -> Tensor {
        self.module
            .forward_ts(&[x, t, intrinsics])
            .unwrap_or_else(|e| panic!("TorchScript denoiser failed (was it validated?): {e}"))
    }
    fn size_multiple(&self) -> usize {
        Self::SIZE_MULTIPLE
    }
}

/// Whether `path` is a TorchScript archive (a zip file) rather than safetensors.
pub fn is_torchscript(path: &Path) -> Result<bool> {
    use std::io::Read;
    let (mut f, _) = crate::nn::shipped::open_model(path)?;
    let mut magic = [0u8; 4];
    Ok(f.read_exact(&mut magic).is_ok() && magic == *b"PK\x03\x04")
}

/// Loads a denoiser: a TorchScript archive, else a safetensors checkpoint.
pub fn load_model(path: &Path, device: Device) -> Result<Box<dyn X0Model>> {
    if is_torchscript(path)? {
        let module = CModule::load_on_device(path, device)
            .map_err(|e| Error::input(path, format!("cannot load the TorchScript denoiser: {e}")))?;
        return Ok(Box::new(TorchScriptModel { module }));
    }
    let (vs, net, _) = load_denoiser(path, device)?;
    Ok(Box::new(NativeModel::new(vs, net)))
}
