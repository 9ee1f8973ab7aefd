#!/usr/bin/env python3
"""Writes small checkpoints the way the authors' trainers save them, for tests/checkpoints.rs.

Usage: official_checkpoints.py OUT_DIR

The networks are PyTorch modules with the authors' state-dict keys at the `tiny` widths (dim 8, dim_mults
1,2,4,8, attention with 4 heads of 32), built from the layers of benchmarks/peers/networks_peers.py with
every parameter drawn at random (seeded). Written to OUT_DIR:

  model-best.pt         the correction trainer's dict: `model` (the MaskUnet state dict as DDP saves it,
                        keys `module.*`), `opt`, `scheduler`, `scaler`, `loss_hist` and `metrics`, which
                        holds an object of a class defined here, so `torch.load(weights_only=True)` refuses
                        the file and any other process has to unpickle a class it cannot import
  model-1.pt            the diffusion trainer's `{'step', 'model', 'opt', 'ema', 'scaler'}`: `model` the
                        GaussianDiffusion state dict (U-Net under `model.`, float32 schedule buffers),
                        `ema` the EMA wrapper's state dict (`ema_model.*` a separate copy, `online_model.*`
                        the very tensors of `model`, `initted` and `step` buffers), `opt` Adam's state
  not-a-trainer.pt      a dict without the trainers' entries
  originals.safetensors every original weight, written apart with plain safetensors: the correction U-Net
                        under `correction.`, the diffusion U-Net's EMA copy under `ema.`, its online
                        weights under `online.` (authors' keys after the prefix)
"""

import copy
import os
import sys

import torch
import torch.nn as nn
from safetensors.torch import save_file

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "benchmarks", "peers"))
import networks_peers as peers  # noqa: E402

UNET = {
    "dim": 8,
    "dim_mults": [1, 2, 4, 8],
    "resnet_groups": 8,
    "attention": True,
    "attn_heads": 4,
    "attn_dim_head": 32,
    "out_channels": 1,
}


def authors_unet(in_channels, cond_dim, final_in_sequential):
    """A U-Net whose children sit at the root, as in the authors' `Unet` / `MaskUnet`."""
    cfg = dict(UNET, in_channels=in_channels, cond_dim=cond_dim, final_conv_in_sequential=final_in_sequential)
    inner = peers.Unet(cfg)
    net = nn.Module()
    for name, child in inner.named_children():
        setattr(net, name, child)
    return net


class MaskUnet(nn.Module):
    def __init__(self):
        super().__init__()
        net = authors_unet(3, None, True)
        for name, child in net.named_children():
            setattr(self, name, child)


class Unet(nn.Module):
    def __init__(self):
        super().__init__()
        dim = UNET["dim"]
        emb = 4 * dim
        self.time_mlp = nn.Sequential(peers.SinusoidalPosEmb(dim), nn.Linear(dim, emb), nn.GELU(), nn.Linear(emb, emb))
        self.param_mlp = nn.Sequential(nn.Linear(4, emb), nn.GELU(), nn.Linear(emb, emb))
        for name, child in authors_unet(1, 2 * emb, False).named_children():
            setattr(self, name, child)


class GaussianDiffusion(nn.Module):
    """The wrapper: the U-Net under `model`, the schedule as float32 buffers beside it."""

    def __init__(self, unet):
        super().__init__()
        self.model = unet
        betas = torch.linspace(1e-4, 0.02, 1000, dtype=torch.float64)
        alphas_cumprod = torch.cumprod(1 - betas, dim=0)
        for name, value in [("betas", betas), ("alphas_cumprod", alphas_cumprod), ("loss_weight", alphas_cumprod / (1 - alphas_cumprod))]:
            self.register_buffer(name, value.to(torch.float32))


class EMA(nn.Module):
    """ema_pytorch 0.2.2's layout: a deep copy, the online model itself, and two bookkeeping buffers."""

    def __init__(self, model):
        super().__init__()
        self.online_model = model
        self.ema_model = copy.deepcopy(model)
        self.register_buffer("initted", torch.tensor(True))
        self.register_buffer("step", torch.tensor(1000))


class DistributedDataParallel(nn.Module):
    """What DDP adds to a state dict: the `module.` prefix."""

    def __init__(self, module):
        super().__init__()
        self.module = module


class SaeMetric:
    """A metric object as the correction trainer keeps them (a class of its own script)."""

    def __init__(self):
        self.best = 0.125
        self.history = [0.5, 0.25, 0.125]


def randomize(module, seed):
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in module.parameters():
            p.copy_(torch.randn(p.shape, generator=g) * 0.1)


def adam_state(module):
    opt = torch.optim.Adam(module.parameters(), lr=1e-4)
    loss = sum((p * p).sum() for p in module.parameters())
    loss.backward()
    opt.step()
    return opt


def main(out):
    os.makedirs(out, exist_ok=True)
    originals = {}

    mask_unet = MaskUnet()
    randomize(mask_unet, 1)
    ddp = DistributedDataParallel(mask_unet)
    opt = adam_state(ddp)
    scheduler = torch.optim.lr_scheduler.ExponentialLR(opt, gamma=0.95)
    torch.save(
        {
            "epoch": 3,
            "model": ddp.state_dict(),
            "opt": opt.state_dict(),
            "scheduler": scheduler.state_dict(),
            "scaler": None,
            "loss_hist": [0.7, 0.6, 0.5],
            "metrics": {"sae": SaeMetric()},
        },
        os.path.join(out, "model-best.pt"),
    )
    originals.update({f"correction.{k}": v.clone() for k, v in mask_unet.state_dict().items()})

    diffusion = GaussianDiffusion(Unet())
    randomize(diffusion, 2)
    ema = EMA(diffusion)
    randomize(ema.ema_model, 3)  # after training the EMA copy differs from the online weights
    opt = adam_state(diffusion)
    model_sd, ema_sd = diffusion.state_dict(), ema.state_dict()
    shared = model_sd["model.init_conv.weight"].untyped_storage().data_ptr()
    assert ema_sd["online_model.model.init_conv.weight"].untyped_storage().data_ptr() == shared
    torch.save({"step": 1000, "model": model_sd, "opt": opt.state_dict(), "ema": ema_sd, "scaler": None}, os.path.join(out, "model-1.pt"))
    originals.update({f"ema.{k}": v.clone() for k, v in ema.ema_model.model.state_dict().items()})
    originals.update({f"online.{k}": v.clone() for k, v in diffusion.model.state_dict().items()})

    torch.save({"weights": torch.zeros(3)}, os.path.join(out, "not-a-trainer.pt"))
    save_file(originals, os.path.join(out, "originals.safetensors"))

    # The files are what the issue says: the safe loader refuses the correction checkpoint, and the
    # diffusion checkpoint's tensors still share storage after loading.
    try:
        torch.load(os.path.join(out, "model-best.pt"), weights_only=True)
        sys.exit("the correction checkpoint loaded with weights_only=True: the fixture is not realistic")
    except Exception:  # noqa: BLE001
        pass
    ck = torch.load(os.path.join(out, "model-1.pt"), weights_only=False)
    a, b = ck["model"]["model.init_conv.weight"], ck["ema"]["online_model.model.init_conv.weight"]
    assert a.untyped_storage().data_ptr() == b.untyped_storage().data_ptr(), "storage not shared after loading"
    print(f"wrote {out}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
