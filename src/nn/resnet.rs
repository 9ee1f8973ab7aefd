//! `Block` and `ResnetBlock` of the U-Net (reference §5.1), with optional FiLM conditioning.

use super::init::{conv, linear};
use super::ws_conv::WsConv2d;
use tch::{nn, nn::Module, Tensor};

/// WeightStandardizedConv2d(3×3) → GroupNorm → [FiLM `x·(scale+1) + shift`] → SiLU.
/// Variables `proj.{weight,bias}`, `norm.{weight,bias}`.
#[derive(Debug)]
pub struct Block {
    pub proj: WsConv2d,
    pub norm: nn::GroupNorm,
}

impl Block {
    pub fn new(p: &nn::Path, c_in: i64, c_out: i64, groups: i64) -> Self {
        Block {
            proj: WsConv2d::new(&(p / "proj"), c_in, c_out, 3, 1),
            norm: nn::group_norm(p / "norm", groups, c_out, Default::default()),
        }
    }

    /// Shapes: `x [B, c_in, H, W]`, `scale_shift` two `[B, c_out, 1, 1]` → `[B, c_out, H, W]`.
    pub fn forward(&self, x: &Tensor, scale_shift: Option<(&Tensor, &Tensor)>) -> Tensor {
        let mut h = self.norm.forward(&self.proj.forward(x));
        if let Some((scale, shift)) = scale_shift {
            h = h * (scale + 1.0) + shift;
        }
        h.silu()
    }
}

/// `block1` (FiLM when conditioned) → `block2` → + residual (1×1 `res_conv` when the width changes).
/// Variables: `mlp.1.{weight,bias}` (SiLU → Linear(cond → 2·c_out), only when conditioned),
/// `block1.*`, `block2.*`, `res_conv.{weight,bias}` (only when `c_in ≠ c_out`).
#[derive(Debug)]
pub struct ResnetBlock {
    pub mlp: Option<nn::Linear>,
    pub block1: Block,
    pub block2: Block,
    pub res_conv: Option<nn::Conv2D>,
    c_out: i64,
}

impl ResnetBlock {
    /// `cond_dim`: width of the conditioning embedding (None: unconditioned).
    pub fn new(p: &nn::Path, c_in: i64, c_out: i64, groups: i64, cond_dim: Option<i64>) -> Self {
        ResnetBlock {
            mlp: cond_dim.map(|d| linear(p / "mlp" / 1, d, 2 * c_out)),
            block1: Block::new(&(p / "block1"), c_in, c_out, groups),
            block2: Block::new(&(p / "block2"), c_out, c_out, groups),
            res_conv: (c_in != c_out).then(|| conv(p / "res_conv", c_in, c_out, 1, 1, 0, true)),
            c_out,
        }
    }

    /// Shapes: `x [B, c_in, H, W]`, `cond [B, cond_dim]` (required iff built with `cond_dim`) →
    /// `[B, c_out, H, W]`.
    pub fn forward(&self, x: &Tensor, cond: Option<&Tensor>) -> Tensor {
        let film = match (&self.mlp, cond) {
            (Some(mlp), Some(c)) => {
                let ss = mlp.forward(&c.silu()).view([-1, 2 * self.c_out, 1, 1]);
                let parts = ss.chunk(2, 1);
                Some((parts[0].shallow_clone(), parts[1].shallow_clone()))
            }
            (None, None) => None,
            (Some(_), None) => panic!("a conditioned ResnetBlock needs its conditioning embedding"),
            (None, Some(_)) => panic!("an unconditioned ResnetBlock was given a conditioning embedding"),
        };
        let h = self.block1.forward(x, film.as_ref().map(|(a, b)| (a, b)));
        let h = self.block2.forward(&h, None);
        match &self.res_conv {
            Some(c) => h + c.forward(x),
            None => h + x,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, Kind};

    #[test]
    fn shapes_and_variable_names_follow_the_reference() {
        let vs = nn::VarStore::new(Device::Cpu);
        let b = ResnetBlock::new(&(vs.root() / "blk"), 16, 8, 8, Some(32));
        let y = b.forward(
            &Tensor::randn([2, 16, 6, 5], (Kind::Float, Device::Cpu)),
            Some(&Tensor::randn([2, 32], (Kind::Float, Device::Cpu))),
        );
        assert_eq!(y.size(), vec![2, 8, 6, 5]);
        let mut names: Vec<String> = vs.variables().into_keys().collect();
        names.sort();
        assert_eq!(
            names,
            [
                "blk.block1.norm.bias",
                "blk.block1.norm.weight",
                "blk.block1.proj.bias",
                "blk.block1.proj.weight",
                "blk.block2.norm.bias",
                "blk.block2.norm.weight",
                "blk.block2.proj.bias",
                "blk.block2.proj.weight",
                "blk.mlp.1.bias",
                "blk.mlp.1.weight",
                "blk.res_conv.bias",
                "blk.res_conv.weight",
            ]
        );
    }
}
