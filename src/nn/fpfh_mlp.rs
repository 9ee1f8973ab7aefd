//! The cheap learned descriptor of issue 16: an MLP from a point's multi-scale FPFH (computed by
//! [`crate::registration::fpfh`]; this file sees only the feature rows) to a unit vector. FPFH rows sum
//! to 200 per angle, so the input is divided by 100 to bring it near unit scale.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use tch::{nn, nn::Module, Tensor};

/// FPFH values per unit of network input.
pub const INPUT_SCALE: f64 = 100.0;

/// Hyperparameters of an [`FpfhMlp`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FpfhMlpConfig {
    /// Input length: 33 per FPFH radius.
    pub input: i64,
    /// Width of the two hidden layers.
    pub hidden: i64,
    /// Descriptor length.
    pub dim: i64,
}

impl Default for FpfhMlpConfig {
    fn default() -> Self {
        FpfhMlpConfig { input: 99, hidden: 128, dim: 32 }
    }
}

/// `forward(fpfh [B, input]) → descriptors [B, dim]`, each of unit length.
#[derive(Debug)]
pub struct FpfhMlp {
    pub config: FpfhMlpConfig,
    layers: nn::Sequential,
}

impl FpfhMlp {
    /// Creates the variables under `p`.
    pub fn new(p: &nn::Path, config: &FpfhMlpConfig) -> Result<Self> {
        let c = *config;
        if c.input < 1 || c.hidden < 1 || c.dim < 1 {
            return Err(Error::config("descriptor.mlp", format!("input, hidden and dim must be positive: {c:?}")));
        }
        let layers = nn::seq()
            .add(nn::linear(p / "fc1", c.input, c.hidden, Default::default()))
            .add_fn(|x| x.relu())
            .add(nn::linear(p / "fc2", c.hidden, c.hidden, Default::default()))
            .add_fn(|x| x.relu())
            .add(nn::linear(p / "fc3", c.hidden, c.dim, Default::default()));
        Ok(FpfhMlp { config: c, layers })
    }

    pub fn forward(&self, fpfh: &Tensor) -> Tensor {
        super::unit_rows(&self.layers.forward(&(fpfh / INPUT_SCALE)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, Kind};

    #[test]
    fn descriptors_have_the_asked_length_and_unit_norm() {
        let vs = nn::VarStore::new(Device::Cpu);
        let net = FpfhMlp::new(&vs.root(), &FpfhMlpConfig { input: 66, hidden: 16, dim: 7 }).unwrap();
        let x = Tensor::rand([5, 66], (Kind::Float, Device::Cpu)) * 20.0;
        let d = net.forward(&x);
        assert_eq!(d.size(), [5, 7]);
        let norms = Vec::<f32>::try_from(d.square().sum_dim_intlist(&[1i64][..], false, Kind::Float)).unwrap();
        assert!(norms.iter().all(|n| (n - 1.0).abs() < 1e-5), "{norms:?}");
        assert!(FpfhMlp::new(&vs.root(), &FpfhMlpConfig { input: 66, hidden: 0, dim: 7 }).is_err());
    }
}
