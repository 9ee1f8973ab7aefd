//! Attention layers of the U-Net (reference §5.1): linear attention at every level, full softmax
//! attention in the middle, each wrapped as `Residual(PreNorm(...))`.

use super::init::conv;
use super::norm::ChannelLayerNorm;
use tch::{nn, nn::Module, Kind, Tensor};

/// Heads and width per head of the official attention layers (4 × 32).
pub const HEADS: i64 = 4;
pub const DIM_HEAD: i64 = 32;

/// Heads and width per head of one attention layer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HeadShape {
    pub heads: i64,
    pub dim_head: i64,
}

impl HeadShape {
    /// The official 4 × 32.
    pub const OFFICIAL: HeadShape = HeadShape { heads: HEADS, dim_head: DIM_HEAD };

    fn hidden(self) -> i64 {
        self.heads * self.dim_head
    }

    fn scale(self) -> f64 {
        (self.dim_head as f64).powf(-0.5)
    }

    /// Shapes: `x [B, C, H, W]` → q, k, v `[B, heads, dim_head, H·W]` and the output shape
    /// `[B, heads·dim_head, H, W]`.
    fn qkv(self, to_qkv: &nn::Conv2D, x: &Tensor) -> (Tensor, Tensor, Tensor, [i64; 4]) {
        let (b, _, h, w) = x.size4().expect("attention input is [B, C, H, W]");
        let parts = to_qkv.forward(x).chunk(3, 1);
        let f = |t: &Tensor| t.reshape([b, self.heads, self.dim_head, h * w]);
        (f(&parts[0]), f(&parts[1]), f(&parts[2]), [b, self.hidden(), h, w])
    }
}

/// Linear attention: q softmax over features, k softmax over positions, `q·32^-½`, `v/(H·W)`,
/// `ctx = k vᵀ`, `out = ctxᵀ q`, then 1×1 conv and channel LayerNorm.
/// Variables `to_qkv.weight`, `to_out.0.{weight,bias}`, `to_out.1.g`.
#[derive(Debug)]
pub struct LinearAttention {
    pub shape: HeadShape,
    pub to_qkv: nn::Conv2D,
    pub to_out: nn::Conv2D,
    pub out_norm: ChannelLayerNorm,
}

impl LinearAttention {
    pub fn new(p: &nn::Path, dim: i64, shape: HeadShape) -> Self {
        LinearAttention {
            shape,
            to_qkv: conv(p / "to_qkv", dim, 3 * shape.hidden(), 1, 1, 0, false),
            to_out: conv(p / "to_out" / 0, shape.hidden(), dim, 1, 1, 0, true),
            out_norm: ChannelLayerNorm::new(&(p / "to_out" / 1), dim),
        }
    }

    /// Shapes: `x [B, dim, H, W]` → `[B, dim, H, W]`.
    pub fn forward(&self, x: &Tensor) -> Tensor {
        let (q, k, v, shape) = self.shape.qkv(&self.to_qkv, x);
        let n = (shape[2] * shape[3]) as f64;
        let q = q.softmax(-2, Kind::Float) * self.shape.scale();
        let k = k.softmax(-1, Kind::Float);
        let v = v / n;
        let ctx = k.matmul(&v.transpose(-1, -2)); // [B, h, d, e]
        let out = ctx.transpose(-1, -2).matmul(&q); // [B, h, e, n]
        self.out_norm.forward(&self.to_out.forward(&out.reshape(shape)))
    }
}

/// Full softmax attention over all positions, `q·32^-½`, then a 1×1 conv.
/// Variables `to_qkv.weight`, `to_out.{weight,bias}`.
#[derive(Debug)]
pub struct Attention {
    pub shape: HeadShape,
    pub to_qkv: nn::Conv2D,
    pub to_out: nn::Conv2D,
}

impl Attention {
    pub fn new(p: &nn::Path, dim: i64, shape: HeadShape) -> Self {
        Attention {
            shape,
            to_qkv: conv(p / "to_qkv", dim, 3 * shape.hidden(), 1, 1, 0, false),
            to_out: conv(p / "to_out", shape.hidden(), dim, 1, 1, 0, true),
        }
    }

    /// Shapes: `x [B, dim, H, W]` → `[B, dim, H, W]` (memory `B·4·(H·W)²` floats).
    pub fn forward(&self, x: &Tensor) -> Tensor {
        let (q, k, v, shape) = self.shape.qkv(&self.to_qkv, x);
        let q = q * self.shape.scale();
        let attn = q.transpose(-1, -2).matmul(&k).softmax(-1, Kind::Float); // [B, h, i, j]
        let out = attn.matmul(&v.transpose(-1, -2)); // [B, h, i, d]
        self.to_out.forward(&out.transpose(-1, -2).reshape(shape))
    }
}

/// Either attention kind.
#[derive(Debug)]
pub enum AttentionKind {
    Linear(LinearAttention),
    Full(Attention),
}

/// `x + attn(norm(x))`: the official `Residual(PreNorm(dim, attn))`.
/// Variables `fn.norm.g` and the attention's under `fn.fn`.
#[derive(Debug)]
pub struct PreNormResidual {
    pub norm: ChannelLayerNorm,
    pub attn: AttentionKind,
}

impl PreNormResidual {
    /// Linear attention (`full = false`, every level) or full attention (the middle).
    pub fn new(p: &nn::Path, dim: i64, full: bool, shape: HeadShape) -> Self {
        let inner = p / "fn";
        let attn = if full {
            AttentionKind::Full(Attention::new(&(&inner / "fn"), dim, shape))
        } else {
            AttentionKind::Linear(LinearAttention::new(&(&inner / "fn"), dim, shape))
        };
        PreNormResidual { norm: ChannelLayerNorm::new(&(&inner / "norm"), dim), attn }
    }

    /// Shapes: `x [B, dim, H, W]` → `[B, dim, H, W]`.
    pub fn forward(&self, x: &Tensor) -> Tensor {
        let h = self.norm.forward(x);
        let y = match &self.attn {
            AttentionKind::Linear(a) => a.forward(&h),
            AttentionKind::Full(a) => a.forward(&h),
        };
        y + x
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Device;

    #[test]
    fn full_attention_matches_an_explicit_loop_over_positions() {
        tch::manual_seed(3);
        let vs = nn::VarStore::new(Device::Cpu);
        let a = Attention::new(&vs.root(), 8, HeadShape::OFFICIAL);
        let x = Tensor::randn([1, 8, 2, 3], (Kind::Float, Device::Cpu));
        let got = a.forward(&x);
        // Reference: per head, per query position i, softmax_j(q_i·k_j·s) weighted sum of v_j.
        let qkv = a.to_qkv.forward(&x).view([3, HEADS, DIM_HEAD, 6]);
        let mut heads = Vec::new();
        for h in 0..HEADS {
            let (q, k, v) = (qkv.get(0).get(h), qkv.get(1).get(h), qkv.get(2).get(h)); // [d, n]
            let mut cols = Vec::new();
            for i in 0..6 {
                let s = (q.select(1, i).unsqueeze(1) * &k).sum_dim_intlist(0, false, Kind::Float)
                    * (DIM_HEAD as f64).powf(-0.5);
                let w = s.softmax(0, Kind::Float);
                cols.push((&v * w.unsqueeze(0)).sum_dim_intlist(1, false, Kind::Float));
            }
            heads.push(Tensor::stack(&cols, 1));
        }
        let expect = a.to_out.forward(&Tensor::cat(&heads, 0).view([1, HEADS * DIM_HEAD, 2, 3]));
        assert!((got - expect).abs().max().double_value(&[]) < 1e-5);
    }

    #[test]
    fn linear_attention_and_wrapper_keep_the_shape_and_names() {
        let vs = nn::VarStore::new(Device::Cpu);
        let r = PreNormResidual::new(&(vs.root() / "a"), 16, false, HeadShape::OFFICIAL);
        let y = r.forward(&Tensor::randn([2, 16, 4, 4], (Kind::Float, Device::Cpu)));
        assert_eq!(y.size(), vec![2, 16, 4, 4]);
        let mut names: Vec<String> = vs.variables().into_keys().collect();
        names.sort();
        assert_eq!(
            names,
            [
                "a.fn.fn.to_out.0.bias",
                "a.fn.fn.to_out.0.weight",
                "a.fn.fn.to_out.1.g",
                "a.fn.fn.to_qkv.weight",
                "a.fn.norm.g"
            ]
        );
    }
}
