//! Weight-standardised 2-D convolution (reference §5.1 `WeightStandardizedConv2d`).

use tch::{nn, Kind, Tensor};

/// Epsilon of the standardisation (the official value for fp32).
const EPS: f64 = 1e-5;

/// A square convolution whose kernel is standardised per output channel before use:
/// `(w − mean) / sqrt(var + 1e-5)` over (in, kh, kw), biased variance. Variables `weight`, `bias`.
#[derive(Debug)]
pub struct WsConv2d {
    pub conv: nn::Conv2D,
    padding: i64,
}

impl WsConv2d {
    /// `c_in → c_out` with a `k`×`k` kernel, stride 1, zero padding `padding`, with bias.
    pub fn new(p: &nn::Path, c_in: i64, c_out: i64, k: i64, padding: i64) -> Self {
        let conv = super::init::conv(p.clone(), c_in, c_out, k, 1, padding, true);
        WsConv2d { conv, padding }
    }

    /// The standardised kernel `[c_out, c_in, k, k]`.
    pub fn standardised_weight(&self) -> Tensor {
        let w = &self.conv.ws;
        let mean = w.mean_dim([1i64, 2, 3].as_slice(), true, Kind::Float);
        let var = w.var_correction([1i64, 2, 3].as_slice(), 0, true);
        (w - mean) * (var + EPS).rsqrt()
    }

    /// Shapes: `x [B, c_in, H, W]` → `[B, c_out, H', W']` (same size for `padding = k / 2`).
    pub fn forward(&self, x: &Tensor) -> Tensor {
        x.conv2d(&self.standardised_weight(), self.conv.bs.as_ref(), [1, 1], [self.padding, self.padding], [1, 1], 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Device;

    #[test]
    fn standardised_kernel_has_zero_mean_and_unit_variance_per_output_channel() {
        tch::manual_seed(1);
        let vs = nn::VarStore::new(Device::Cpu);
        let c = WsConv2d::new(&vs.root(), 3, 5, 3, 1);
        let w = c.standardised_weight();
        let mean = w.mean_dim([1i64, 2, 3].as_slice(), false, Kind::Float).abs().max().double_value(&[]);
        let var = w.var_correction([1i64, 2, 3].as_slice(), 0, false);
        assert!(mean < 1e-6, "{mean}");
        // Unit variance up to the 1e-5 epsilon (the raw kernel's variance is about 1/(3·27)).
        assert!((var - 1.0).abs().max().double_value(&[]) < 5e-3);
        let y = c.forward(&Tensor::ones([2, 3, 7, 6], (Kind::Float, Device::Cpu)));
        assert_eq!(y.size(), vec![2, 5, 7, 6]);
    }
}
