#!/usr/bin/env python3
"""Clean-frame denoising error of diffusion checkpoints, per time step (docs/lab/2026-12-01-diffusion-tiny-models.md).

Usage: denoiser_error.py SEQUENCE_DIR CHECKPOINT [CHECKPOINT ...]

For frames 300, 320, ..., 380 of a 3DMatch-layout sequence (16-bit PNG depth in mm, 585 px focal length
at 640x480 as 7-Scenes): resize to 341x256 (nearest neighbour), centre-crop 256x256, map to network space
(2 z / 10 - 1, missing = -1), noise to x_t = sqrt(abar_t) x0 + sqrt(1 - abar_t) eps for a few t, and
print the mean |x0_pred - x0| in metres over valid pixels for each checkpoint's sampling (EMA) network,
beside the same error of a 5x5 box filter of x_t / sqrt(abar_t). The network is the PyTorch mirror of
networks_peers.py, loaded with strict key matching; abar_t is the official sigmoid schedule.
"""

import json
import math
import os
import sys

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image
from safetensors import safe_open

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import networks_peers as peers  # noqa: E402

STEPS = [0, 2, 5, 10, 20]
FRAMES = [300, 320, 340, 360, 380]


def load(path):
    f = safe_open(path, "pt")
    net = json.loads(f.metadata()["pointreggpt"])["net"]
    keys = list(f.keys())
    prefix = next(p for p in ("ema.ema_model.model.", "model.") if any(k.startswith(p) for k in keys))
    state = {k[len(prefix):]: f.get_tensor(k) for k in keys if k.startswith(prefix)}
    model = peers.Denoiser(net)
    model.load(state)
    return model.eval()


def alpha_bar():
    t = torch.linspace(0, 1000, 1001, dtype=torch.float64) / 1000
    v_start, v_end = torch.tensor(-3.0).double().sigmoid(), torch.tensor(3.0).double().sigmoid()
    ac = (-(t * 6 - 3).sigmoid() + v_end) / (v_end - v_start)
    ac = ac / ac[0]
    betas = (1 - ac[1:] / ac[:-1]).clip(0, 0.999)
    return torch.cumprod(1 - betas, 0)


def frame(seq, i):
    d = np.array(Image.open(os.path.join(seq, f"frame-{i:06d}.depth.png"))).astype(np.float32) / 1000
    d[d >= 65.0] = 0  # Kinect v1 writes 65535 for invalid
    a = np.array(Image.fromarray(d).resize((341, 256), Image.NEAREST))
    left = (341 - 256) // 2
    a = a[:, left:left + 256]
    s = 256 / 480
    k = torch.tensor([[585 * s, 585 * s, 320 * s - left, 240 * s]], dtype=torch.float32)
    x = np.where((a > 0.5) & (a < 10), 2 * a / 10 - 1, -1).astype(np.float32)
    return torch.from_numpy(x)[None, None], k


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    torch.set_num_threads(1)
    seq, paths = sys.argv[1], sys.argv[2:]
    ab = alpha_bar()
    frames = [frame(seq, i) for i in FRAMES]
    print("checkpoint\tt\tnoise_sd_m\tmodel_err_m\tbox5_err_m")
    for path in paths:
        model = load(path)
        g = torch.Generator().manual_seed(0)
        for t in STEPS:
            a = ab[t].item()
            errs, box = [], []
            for x0, k in frames:
                valid = x0 > -1
                xt = x0 * math.sqrt(a) + torch.randn(x0.shape, generator=g) * math.sqrt(1 - a)
                with torch.no_grad():
                    pred = model(xt, torch.tensor([t]), k).clamp(-1, 1)
                errs.append((pred - x0).abs()[valid].mean().item() * 5)
                b = F.avg_pool2d(xt / math.sqrt(a), 5, 1, 2, count_include_pad=False)
                box.append((b - x0).abs()[valid].mean().item() * 5)
            sd = math.sqrt((1 - a) / a) * 5
            print(f"{path}\t{t}\t{sd:.3f}\t{np.mean(errs):.4f}\t{np.mean(box):.4f}")


if __name__ == "__main__":
    main()
