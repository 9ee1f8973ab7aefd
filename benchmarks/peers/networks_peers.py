#!/usr/bin/env python3
"""PyTorch peer of the networks benchmark (driven by benchmarks/networks.rs).

Usage: networks_peers.py DIR

DIR holds what the Rust side timed, written by it:
  params.json                    {"threads", "nets": {name: {"kind", "unet", ...}}} (our configs as JSON)
  <name>.weights.safetensors     the network's variables under our (= the authors') state-dict keys
  <name>.io.safetensors          its inputs and our output on them (float32):
                                   denoiser:   x [B,1,H,W], t [B] (integer steps), k [B,4], out [B,1,H,W]
                                   correction: depth [B,1,H,W] in [0, 1], out [B,1,H,W] keep probability

For each network the script builds the same architecture in plain PyTorch (lucidrains' denoising-diffusion
U-Net as the authors used it: weight-standardised conv blocks, GroupNorm, FiLM, linear attention per level,
full attention in the middle; the correction network is DepthAugment + that U-Net + sigmoid) and loads the
weights with strict key matching. It then prints `ready` and answers one command per stdin line, so the
Rust side can interleave its runs with ours (both then see the same load on a shared machine):
  time NET     one forward under torch.no_grad() (thread count from params.json); the first one's output
               is the one compared with ours
  diff NET     compare that output with ours
  quit         (or end of input) exit

Prints tab-separated lines:
  info <TAB> name <TAB> value
  params <TAB> net <TAB> count                       parameters of the PyTorch module
  ready                                              every network is built; commands are read from now on
  time <TAB> net <TAB> ms                            wall time of one forward (time.perf_counter)
  diff <TAB> net <TAB> max |peer - ours| <TAB> max |ours|
  error <TAB> net <TAB> message                      this network's peer failed (others still run)
  unavailable <TAB> reason                           no peer can run (e.g. torch is not installed)
"""

import json
import math
import os
import sys
import time


def emit(*fields):
    print("\t".join(str(f).replace("\t", " ").replace("\n", " ") for f in fields), flush=True)


try:
    import torch
    import torch.nn as nn
    import torch.nn.functional as F
except Exception as e:  # noqa: BLE001 - ImportError, or a broken shared library
    emit("unavailable", f"python could not import torch ({type(e).__name__}: {e}); run scripts/install-network-peers.sh")
    sys.exit(0)

try:
    from safetensors.torch import load_file
except Exception as e:  # noqa: BLE001
    emit("unavailable", f"python could not import safetensors ({type(e).__name__}: {e}); run scripts/install-network-peers.sh")
    sys.exit(0)


# ---------------------------------------------------------------------------------------------
# Layers (reference §5.1)


class WeightStandardizedConv2d(nn.Conv2d):
    """Conv whose kernel is standardised per output channel: (w - mean) / sqrt(var + 1e-5), biased var."""

    def forward(self, x):
        w = self.weight
        mean = w.mean(dim=(1, 2, 3), keepdim=True)
        var = w.var(dim=(1, 2, 3), unbiased=False, keepdim=True)
        return F.conv2d(x, (w - mean) * (var + 1e-5).rsqrt(), self.bias, self.stride, self.padding)


class ChannelLayerNorm(nn.Module):
    """Per-pixel normalisation over channels with a gain `g` only."""

    def __init__(self, dim):
        super().__init__()
        self.g = nn.Parameter(torch.ones(1, dim, 1, 1))

    def forward(self, x):
        mean = x.mean(dim=1, keepdim=True)
        var = x.var(dim=1, unbiased=False, keepdim=True)
        return (x - mean) * (var + 1e-5).rsqrt() * self.g


class Block(nn.Module):
    def __init__(self, c_in, c_out, groups):
        super().__init__()
        self.proj = WeightStandardizedConv2d(c_in, c_out, 3, padding=1)
        self.norm = nn.GroupNorm(groups, c_out)

    def forward(self, x, scale_shift=None):
        x = self.norm(self.proj(x))
        if scale_shift is not None:
            scale, shift = scale_shift
            x = x * (scale + 1) + shift
        return F.silu(x)


class ResnetBlock(nn.Module):
    def __init__(self, c_in, c_out, groups, cond_dim=None):
        super().__init__()
        self.mlp = nn.Sequential(nn.SiLU(), nn.Linear(cond_dim, 2 * c_out)) if cond_dim else None
        self.block1 = Block(c_in, c_out, groups)
        self.block2 = Block(c_out, c_out, groups)
        self.res_conv = nn.Conv2d(c_in, c_out, 1) if c_in != c_out else nn.Identity()

    def forward(self, x, cond=None):
        scale_shift = None
        if self.mlp is not None:
            scale_shift = self.mlp(cond)[:, :, None, None].chunk(2, dim=1)
        h = self.block1(x, scale_shift)
        h = self.block2(h)
        return h + self.res_conv(x)


def split_heads(qkv_conv, x, heads, dim_head):
    b, _, h, w = x.shape
    q, k, v = qkv_conv(x).chunk(3, dim=1)
    return [t.reshape(b, heads, dim_head, h * w) for t in (q, k, v)]


class LinearAttention(nn.Module):
    def __init__(self, dim, heads, dim_head):
        super().__init__()
        self.heads, self.dim_head = heads, dim_head
        hidden = heads * dim_head
        self.to_qkv = nn.Conv2d(dim, 3 * hidden, 1, bias=False)
        self.to_out = nn.Sequential(nn.Conv2d(hidden, dim, 1), ChannelLayerNorm(dim))

    def forward(self, x):
        b, _, h, w = x.shape
        q, k, v = split_heads(self.to_qkv, x, self.heads, self.dim_head)
        q = q.softmax(dim=-2) * self.dim_head**-0.5
        k = k.softmax(dim=-1)
        v = v / (h * w)
        context = torch.einsum("bhdn,bhen->bhde", k, v)
        out = torch.einsum("bhde,bhdn->bhen", context, q)
        return self.to_out(out.reshape(b, self.heads * self.dim_head, h, w))


class Attention(nn.Module):
    def __init__(self, dim, heads, dim_head):
        super().__init__()
        self.heads, self.dim_head = heads, dim_head
        hidden = heads * dim_head
        self.to_qkv = nn.Conv2d(dim, 3 * hidden, 1, bias=False)
        self.to_out = nn.Conv2d(hidden, dim, 1)

    def forward(self, x):
        b, _, h, w = x.shape
        q, k, v = split_heads(self.to_qkv, x, self.heads, self.dim_head)
        q = q * self.dim_head**-0.5
        attn = torch.einsum("bhdi,bhdj->bhij", q, k).softmax(dim=-1)
        out = torch.einsum("bhij,bhdj->bhdi", attn, v)
        return self.to_out(out.reshape(b, self.heads * self.dim_head, h, w))


class PreNorm(nn.Module):
    def __init__(self, dim, fn):
        super().__init__()
        self.fn = fn
        self.norm = ChannelLayerNorm(dim)

    def forward(self, x):
        return self.fn(self.norm(x))


class Residual(nn.Module):
    def __init__(self, fn):
        super().__init__()
        self.fn = fn

    def forward(self, x):
        return self.fn(x) + x


# ---------------------------------------------------------------------------------------------
# The U-Net skeleton (reference §4.1 / §5.1), configured by our UnetConfig (JSON)


class Unet(nn.Module):
    def __init__(self, cfg):
        super().__init__()
        dim, groups, cond = cfg["dim"], cfg["resnet_groups"], cfg["cond_dim"]
        heads, dim_head = cfg["attn_heads"], cfg["attn_dim_head"]
        dims = [dim] + [dim * m for m in cfg["dim_mults"]]
        pairs = list(zip(dims[:-1], dims[1:]))
        levels = len(pairs)

        def attention(width, full):
            if not cfg["attention"]:
                return nn.Identity()
            inner = Attention(width, heads, dim_head) if full else LinearAttention(width, heads, dim_head)
            return Residual(PreNorm(width, inner))

        self.init_conv = nn.Conv2d(cfg["in_channels"], dim, 7, padding=3)
        self.downs = nn.ModuleList()
        for i, (c_in, c_out) in enumerate(pairs):
            last = i + 1 == levels
            down = nn.Conv2d(c_in, c_out, 3, padding=1) if last else nn.Conv2d(c_in, c_out, 4, 2, 1)
            blocks = [ResnetBlock(c_in, c_in, groups, cond), ResnetBlock(c_in, c_in, groups, cond)]
            self.downs.append(nn.ModuleList(blocks + [attention(c_in, False), down]))
        mid = dims[-1]
        self.mid_block1 = ResnetBlock(mid, mid, groups, cond)
        self.mid_attn = attention(mid, True)
        self.mid_block2 = ResnetBlock(mid, mid, groups, cond)
        self.ups = nn.ModuleList()
        for i, (c_in, c_out) in enumerate(reversed(pairs)):
            last = i + 1 == levels
            conv = nn.Conv2d(c_out, c_in, 3, padding=1)
            up = conv if last else nn.Sequential(nn.Upsample(scale_factor=2, mode="nearest"), conv)
            self.ups.append(
                nn.ModuleList(
                    [
                        ResnetBlock(c_out + c_in, c_out, groups, cond),
                        ResnetBlock(c_out + c_in, c_out, groups, cond),
                        attention(c_out, False),
                        up,
                    ]
                )
            )
        self.final_res_block = ResnetBlock(2 * dim, dim, groups, cond)
        conv = nn.Conv2d(dim, cfg["out_channels"], 1)
        # The correction network's final layer is Sequential(conv, Sigmoid) -> key final_conv.0.*.
        self.final_conv = nn.Sequential(conv, nn.Sigmoid()) if cfg["final_conv_in_sequential"] else conv

    def forward(self, x, cond=None):
        x = self.init_conv(x)
        r = x
        skips = []
        for block1, block2, attn, down in self.downs:
            x = block1(x, cond)
            skips.append(x)
            x = attn(block2(x, cond))
            skips.append(x)
            x = down(x)
        x = self.mid_block2(self.mid_attn(self.mid_block1(x, cond)), cond)
        for block1, block2, attn, up in self.ups:
            x = block1(torch.cat((x, skips.pop()), dim=1), cond)
            x = block2(torch.cat((x, skips.pop()), dim=1), cond)
            x = up(attn(x))
        x = self.final_res_block(torch.cat((x, r), dim=1), cond)
        return self.final_conv(x)


class SinusoidalPosEmb(nn.Module):
    def __init__(self, dim):
        super().__init__()
        self.dim = dim

    def forward(self, t):
        half = self.dim // 2
        freqs = torch.exp(torch.arange(half, device=t.device, dtype=torch.float32) * (-math.log(10000) / (half - 1)))
        a = t.float()[:, None] * freqs[None, :]
        return torch.cat((a.sin(), a.cos()), dim=-1)


class Denoiser(nn.Module):
    """x0 = Unet(x_t, FiLM(time_mlp(t) ++ param_mlp(K · intrinsics_scale)))."""

    def __init__(self, cfg):
        super().__init__()
        unet = cfg["unet"]
        dim = unet["dim"]
        emb = 4 * dim
        self.intrinsics_scale = cfg["intrinsics_scale"]
        self.time_mlp = nn.Sequential(SinusoidalPosEmb(dim), nn.Linear(dim, emb), nn.GELU(), nn.Linear(emb, emb))
        self.param_mlp = nn.Sequential(nn.Linear(4, emb), nn.GELU(), nn.Linear(emb, emb))
        self.unet = Unet(unet)

    def forward(self, x, t, k):
        cond = torch.cat((self.time_mlp(t), self.param_mlp(k.float() * self.intrinsics_scale)), dim=1)
        return self.unet(x, cond)

    def load(self, state):
        # The U-Net's keys sit at the root of the authors' state dict, beside time_mlp / param_mlp.
        own = {k: v for k, v in state.items() if k.startswith(("time_mlp.", "param_mlp."))}
        own.update({f"unet.{k}": v for k, v in state.items() if not k.startswith(("time_mlp.", "param_mlp."))})
        self.load_state_dict(own, strict=True)


def depth_augment(d):
    """cat[d, mn, mn - d]: mn the 3x3 minimum over valid (> 0) neighbours, plain 3x3 min where none."""
    d_inf = d.masked_fill(d == 0, float("inf"))
    mn = -F.max_pool2d(-d_inf, 3, 1, 1)
    mn0 = -F.max_pool2d(-d, 3, 1, 1)
    mn = torch.where(torch.isinf(mn), mn0, mn)
    return torch.cat((d, mn, mn - d), dim=1)


class MaskUnet(nn.Module):
    """The correction network: DepthAugment (when on) + U-Net ending in a sigmoid."""

    def __init__(self, cfg):
        super().__init__()
        self.augment = cfg["augment"]
        self.unet = Unet(cfg["unet"])

    def forward(self, depth):
        return self.unet(depth_augment(depth) if self.augment else depth)

    def load(self, state):
        self.unet.load_state_dict(state, strict=True)


# ---------------------------------------------------------------------------------------------
# The session: build every network, then answer the Rust side's commands one at a time, so the two
# sides' runs interleave and share whatever load the machine has at that moment.


class Net:
    def __init__(self, d, name, spec):
        io = load_file(os.path.join(d, f"{name}.io.safetensors"))
        state = load_file(os.path.join(d, f"{name}.weights.safetensors"))
        if spec["kind"] == "denoiser":
            model = Denoiser(spec)
            x, t, k = io["x"], io["t"].round().long(), io["k"]
            self.run = lambda: model(x, t, k)  # noqa: E731
        elif spec["kind"] == "correction":
            model = MaskUnet(spec)
            depth = io["depth"]
            self.run = lambda: model(depth)  # noqa: E731
        else:
            raise ValueError(f"unknown network kind {spec['kind']}")
        model.load(state)
        model.eval()
        self.params = sum(p.numel() for p in model.parameters())
        self.ours = io["out"]
        self.out = None

    def time(self):
        """One forward under no_grad; keeps the first output for the comparison."""
        with torch.no_grad():
            t0 = time.perf_counter()
            out = self.run()
            ms = (time.perf_counter() - t0) * 1e3
        if self.out is None:
            self.out = out
        return ms

    def diff(self):
        if self.out is None:
            raise ValueError("no forward ran yet")
        if self.out.shape != self.ours.shape:
            raise ValueError(f"output shape {tuple(self.out.shape)} differs from ours {tuple(self.ours.shape)}")
        return (self.out - self.ours).abs().max().item(), self.ours.abs().max().item()


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    d = sys.argv[1]
    with open(os.path.join(d, "params.json")) as f:
        params = json.load(f)
    torch.set_num_threads(int(params["threads"]))
    from importlib import metadata

    emit("info", "python", sys.version.split()[0])
    emit("info", "torch", torch.__version__)
    emit("info", "safetensors", metadata.version("safetensors"))
    emit("info", "torch threads", torch.get_num_threads())
    nets = {}
    for name, spec in params["nets"].items():
        try:
            nets[name] = Net(d, name, spec)
            emit("params", name, nets[name].params)
        except Exception as e:  # noqa: BLE001 - one failing network must not hide the other
            emit("error", name, f"{type(e).__name__}: {e}")
    emit("ready")
    while True:
        line = sys.stdin.readline()
        if not line or line.strip() == "quit":
            return
        command, _, name = line.strip().partition(" ")
        if name not in nets:
            emit("error", name, "no such network (it failed to load)")
            continue
        try:
            if command == "time":
                emit("time", name, f"{nets[name].time():.3f}")
            elif command == "diff":
                emit("diff", name, *(f"{v:.3e}" for v in nets[name].diff()))
            else:
                emit("error", name, f"unknown command {command}")
        except Exception as e:  # noqa: BLE001
            emit("error", name, f"{type(e).__name__}: {e}")


if __name__ == "__main__":
    main()
