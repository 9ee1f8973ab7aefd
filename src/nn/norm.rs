//! Layer normalisation across channels per pixel, with a gain only (reference §5.1 `LayerNorm`).

use tch::{nn, Tensor};

const EPS: f64 = 1e-5;

/// `(x − mean_c) / sqrt(var_c + 1e-5) · g`, statistics over the channel axis of each pixel (biased
/// variance). Variable `g` of shape `[1, C, 1, 1]`, initialised to ones.
#[derive(Debug)]
pub struct ChannelLayerNorm {
    pub g: Tensor,
}

impl ChannelLayerNorm {
    pub fn new(p: &nn::Path, channels: i64) -> Self {
        ChannelLayerNorm { g: p.var("g", &[1, channels, 1, 1], nn::Init::Const(1.0)) }
    }

    /// Shapes: `x [B, C, H, W]` → `[B, C, H, W]`.
    pub fn forward(&self, x: &Tensor) -> Tensor {
        let mean = x.mean_dim(1, true, x.kind());
        let var = x.var_correction(1, 0, true);
        (x - mean) * (var + EPS).rsqrt() * &self.g
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, Kind};

    #[test]
    fn normalises_each_pixel_over_channels() {
        let vs = nn::VarStore::new(Device::Cpu);
        let n = ChannelLayerNorm::new(&vs.root(), 4);
        let x = Tensor::from_slice(&[1.0f32, 2.0, 3.0, 4.0, 10.0, 10.0, 10.0, 14.0]).view([1, 4, 1, 2]);
        let y = n.forward(&x);
        let m = y.mean_dim(1, false, Kind::Float).abs().max().double_value(&[]);
        assert!(m < 1e-6);
        // Pixel 0: values 1,3,10,10 → mean 6, biased var 16.5.
        let expect = (1.0 - 6.0) / (16.5f64 + 1e-5).sqrt();
        assert!((y.double_value(&[0, 0, 0, 0]) - expect).abs() < 1e-5);
    }
}
