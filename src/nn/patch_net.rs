//! The patch descriptor network (issue 16): a 3D ConvNet from a `voxels`³ TDF patch
//! ([`crate::registration::patch`]) to a unit vector. Two stride-2 convolutions bring the cube to a quarter
//! of its edge, a convolution as wide as what is left makes it one voxel, a linear layer gives the
//! descriptor.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use tch::{nn, nn::Module, Tensor};

/// Hyperparameters of a [`PatchNet`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PatchNetConfig {
    /// Voxels along a patch edge (a multiple of 4).
    pub voxels: i64,
    /// Channels of the first convolution (then ×2, ×4, ×4).
    pub width: i64,
    /// Descriptor length.
    pub dim: i64,
}

impl Default for PatchNetConfig {
    fn default() -> Self {
        PatchNetConfig { voxels: 16, width: 8, dim: 32 }
    }
}

/// `forward(patches [B, 1, n, n, n]) → descriptors [B, dim]`, each of unit length.
#[derive(Debug)]
pub struct PatchNet {
    pub config: PatchNetConfig,
    layers: nn::Sequential,
}

impl PatchNet {
    /// Creates the variables under `p`.
    pub fn new(p: &nn::Path, config: &PatchNetConfig) -> Result<Self> {
        let c = *config;
        if c.voxels < 4 || c.voxels % 4 != 0 || c.width < 1 || c.dim < 1 {
            return Err(Error::config("descriptor.net", format!("voxels must be a positive multiple of 4 and width, dim positive: {c:?}")));
        }
        let conv = |i: i64, o: i64, k: i64, stride: i64, pad: i64, name: &str| {
            nn::conv3d(p / name, i, o, k, nn::ConvConfig { stride, padding: pad, ..Default::default() })
        };
        let w = c.width;
        let layers = nn::seq()
            .add(conv(1, w, 3, 1, 1, "conv1"))
            .add_fn(|x| x.relu())
            .add(conv(w, 2 * w, 3, 2, 1, "conv2"))
            .add_fn(|x| x.relu())
            .add(conv(2 * w, 4 * w, 3, 2, 1, "conv3"))
            .add_fn(|x| x.relu())
            .add(conv(4 * w, 4 * w, c.voxels / 4, 1, 0, "conv4"))
            .add_fn(|x| x.relu().flatten(1, -1))
            .add(nn::linear(p / "fc", 4 * w, c.dim, Default::default()));
        Ok(PatchNet { config: c, layers })
    }

    pub fn forward(&self, patches: &Tensor) -> Tensor {
        super::unit_rows(&self.layers.forward(patches))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, Kind};

    #[test]
    fn descriptors_have_the_asked_length_and_unit_norm() {
        let vs = nn::VarStore::new(Device::Cpu);
        let net = PatchNet::new(&vs.root(), &PatchNetConfig { voxels: 8, width: 4, dim: 5 }).unwrap();
        let x = Tensor::rand([3, 1, 8, 8, 8], (Kind::Float, Device::Cpu));
        let d = net.forward(&x);
        assert_eq!(d.size(), [3, 5]);
        let norms = Vec::<f32>::try_from(d.square().sum_dim_intlist(&[1i64][..], false, Kind::Float)).unwrap();
        assert!(norms.iter().all(|n| (n - 1.0).abs() < 1e-5), "{norms:?}");
        assert!(PatchNet::new(&vs.root(), &PatchNetConfig { voxels: 6, width: 4, dim: 5 }).is_err());
    }
}
