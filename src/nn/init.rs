//! Layer constructors with PyTorch's default initialisation (`U(±1/√fan_in)` for weights and biases),
//! so freshly made networks start at the scale the reference's code trains from.

use tch::nn;

fn uniform(fan_in: i64) -> nn::Init {
    let b = 1.0 / (fan_in as f64).sqrt();
    nn::Init::Uniform { lo: -b, up: b }
}

/// A `k`×`k` convolution `c_in → c_out` (variables `weight`, and `bias` when `bias`).
pub fn conv(p: nn::Path, c_in: i64, c_out: i64, k: i64, stride: i64, padding: i64, bias: bool) -> nn::Conv2D {
    let init = uniform(c_in * k * k);
    nn::conv2d(
        p,
        c_in,
        c_out,
        k,
        nn::ConvConfig { stride, padding, bias, ws_init: init, bs_init: init, ..Default::default() },
    )
}

/// A linear layer `d_in → d_out` (variables `weight`, `bias`).
pub fn linear(p: nn::Path, d_in: i64, d_out: i64) -> nn::Linear {
    let init = uniform(d_in);
    nn::linear(p, d_in, d_out, nn::LinearConfig { ws_init: init, bs_init: Some(init), bias: true })
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Device;

    #[test]
    fn weights_and_biases_lie_within_one_over_root_fan_in() {
        tch::manual_seed(0);
        let vs = nn::VarStore::new(Device::Cpu);
        let c = conv(vs.root() / "c", 4, 16, 3, 1, 1, true);
        let b = 1.0 / 36f64.sqrt();
        for t in [&c.ws, c.bs.as_ref().unwrap()] {
            let m = t.abs().max().double_value(&[]);
            assert!(m <= b && m > 0.5 * b, "{m} vs {b}");
        }
    }
}
