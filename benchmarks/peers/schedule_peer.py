#!/usr/bin/env python3
"""Known answers for the `paper` noise schedule, computed by PyTorch itself.

Usage: schedule_peer.py

Runs the authors' `sigmoid_beta_schedule(1000, start=-3, end=3, tau=1)` (denoising-diffusion-pytorch, as
their repository has it, see /work/shared/reference/official-implementation.md section 5.2) with their dtypes:
the end points `torch.tensor(start / tau).sigmoid()` are float32 tensors, `t` is a float64 linspace, and
the mix promotes to float64. Prints, as Rust literals, beta_t and alphas_cumprod_t (the float64 values before
the authors cast their buffers to float32) at a few steps, and a checksum of all 1000 float32 buffer values
(sum of (t + 1) * bits), for the table in `src/diffusion/schedule.rs` (test
`the_paper_schedule_matches_pytorch`). Run once; the printed table is committed.
"""

import numpy as np
import torch

STEPS = [0, 1, 19, 499, 500, 974, 975, 976, 990, 998, 999]


def sigmoid_beta_schedule(timesteps, start=-3, end=3, tau=1):
    """The authors' function, line for line (clamp_min is unused there too)."""
    steps = timesteps + 1
    t = torch.linspace(0, timesteps, steps, dtype=torch.float64) / timesteps
    v_start = torch.tensor(start / tau).sigmoid()
    v_end = torch.tensor(end / tau).sigmoid()
    alphas_cumprod = (-((t * (end - start) + start) / tau).sigmoid() + v_end) / (v_end - v_start)
    alphas_cumprod = alphas_cumprod / alphas_cumprod[0]
    betas = 1 - (alphas_cumprod[1:] / alphas_cumprod[:-1])
    return torch.clip(betas, 0, 0.999)


def main():
    betas = sigmoid_beta_schedule(1000)
    assert betas.dtype == torch.float64
    # GaussianDiffusion.__init__: alphas = 1 - betas; alphas_cumprod = torch.cumprod(alphas, dim=0).
    alphas_cumprod = torch.cumprod(1.0 - betas, dim=0)
    v_start, v_end = torch.tensor(-3.0).sigmoid(), torch.tensor(3.0).sigmoid()
    print(f"// torch {torch.__version__}: v_start = {v_start.item()!r} ({v_start.dtype}), v_end = {v_end.item()!r}")
    print("// (t, beta_t, alphas_cumprod_t)")
    for s in STEPS:
        print(f"({s}, {betas[s].item()!r}, {alphas_cumprod[s].item()!r}),")
    weights = np.arange(1, 1001, dtype=np.uint64)
    for name, v in [("betas", betas), ("alphas_cumprod", alphas_cumprod)]:
        bits = v.float().numpy().view(np.uint32).astype(np.uint64)
        print(f"// float32 {name} checksum: {int((bits * weights).sum())}")


if __name__ == "__main__":
    main()
