#!/usr/bin/env python3
"""Converts the authors' PyTorch checkpoints to the safetensors files pointreggpt loads.

Usage:
  python3 scripts/convert-official.py correction model-best.pt models/correction-official.safetensors
  python3 scripts/convert-official.py diffusion model-XXX.pt models/diffusion-official.safetensors

correction  the depth-correction trainer's checkpoint, a dict holding `model` (the MaskUnet state dict)
            beside the optimiser, scheduler, loss history and metric objects. The state dict is written under
            its own keys (`init_conv.weight`, ..., `final_conv.0.weight`), as src/nn/checkpoint.rs reads it.
diffusion   the diffusion trainer's checkpoint `{'step', 'model', 'opt', 'ema', 'scaler'}`. `model` (the
            GaussianDiffusion: the U-Net under `model.`, schedule buffers beside it) is written under
            `model.`, the EMA's copy under `ema.ema_model.`; src/diffusion/checkpoint.rs samples with
            `ema.ema_model.model.*`. The EMA's `online_model` is the trainer's `model` itself (the same
            storage), so it is not written twice. The optimiser and scaler states are not converted: sampling
            and `train diffusion --init` need the weights only.

Only floating-point tensors are kept (each as a contiguous float32 copy), a DDP `module.` prefix is removed,
and the output has no metadata: pointreggpt infers the widths from the tensor shapes. Needs torch and
safetensors (scripts/install-network-peers.sh installs both).
"""

import argparse
import os
import pickle
import sys
import types

KINDS = ("correction", "diffusion")


class ConvertError(Exception):
    pass


class _Unknown:
    """Stands in for a class the checkpoint names but this process cannot import (the trainers' metric
    classes, defined in their own scripts): its state is kept as a plain attribute and never used."""

    def __init__(self, *args, **kwargs):
        self.args = args

    def __setstate__(self, state):
        self.state = state


class _Unpickler(pickle.Unpickler):
    def find_class(self, module, name):
        try:
            return super().find_class(module, name)
        except (AttributeError, ImportError):
            return type(name, (_Unknown,), {"__module__": module})


# torch.load's pickle_module: the standard pickle with the lenient class lookup above.
_PICKLE = types.ModuleType("lenient_pickle")
_PICKLE.Unpickler = _Unpickler
_PICKLE.load = lambda f, **kw: _Unpickler(f, **kw).load()
_PICKLE.__dict__.update({k: getattr(pickle, k) for k in ("UnpicklingError", "HIGHEST_PROTOCOL")})


def load_checkpoint(torch, path):
    if not os.path.isfile(path):
        raise ConvertError("no such file")
    # weights_only=False: the correction trainer's checkpoint pickles metric objects, which torch's
    # weights-only loader refuses. Unpickling RUNS CODE named in the file, so convert only files you trust.
    try:
        return torch.load(path, map_location="cpu", weights_only=False, pickle_module=_PICKLE)
    except Exception as e:  # noqa: BLE001 - torch raises many kinds for a file it cannot read
        raise ConvertError(f"torch.load cannot read it as a PyTorch checkpoint ({type(e).__name__}: {e})") from e


def entry(ck, key, kind):
    """The state dict `ck[key]` of a trainer's checkpoint dict."""
    if not isinstance(ck, dict):
        raise ConvertError(f"holds a {type(ck).__name__}, not the {kind} trainer's checkpoint dict")
    if key not in ck:
        keys = ", ".join(repr(k) for k in list(ck)[:4]) + (", ..." if len(ck) > 4 else "")
        raise ConvertError(f"has no `{key}` entry (it has {keys}): not a {kind} checkpoint of the authors' trainer")
    sd = ck[key]
    if not hasattr(sd, "items"):
        raise ConvertError(f"its `{key}` entry is a {type(sd).__name__}, not a state dict")
    return sd


def float_tensors(torch, sd, prefix):
    """The floating-point tensors of a state dict as contiguous float32 copies under `prefix`, a DDP
    `module.` prefix removed. The copies matter: tensors sharing storage (the diffusion checkpoint's
    `model.*` and `ema.online_model.*`) are refused by safetensors' save_file."""
    out = {}
    for k, v in sd.items():
        if torch.is_tensor(v) and v.is_floating_point():
            k = str(k)
            out[prefix + (k[len("module."):] if k.startswith("module.") else k)] = v.detach().float().clone().contiguous()
    return out


def convert_correction(torch, ck):
    out = float_tensors(torch, entry(ck, "model", "correction"), "")
    if "model.init_conv.weight" in out:
        raise ConvertError("its `model` is a GaussianDiffusion (keys `model.*`): a diffusion checkpoint, convert it with `diffusion`")
    for key in ("init_conv.weight", "final_conv.0.weight"):
        if key not in out:
            raise ConvertError(f"its `model` state dict has no `{key}`: not the authors' MaskUnet")
    if any(".mlp." in k for k in out):
        raise ConvertError("its `model` has time-conditioned ResnetBlocks: a diffusion U-Net, convert it with `diffusion`")
    return out


def convert_diffusion(torch, ck):
    out = float_tensors(torch, entry(ck, "model", "diffusion"), "model.")
    if "model.model.init_conv.weight" not in out:
        if "model.init_conv.weight" in out and "model.final_conv.0.weight" in out:
            raise ConvertError("its `model` is a MaskUnet: a correction checkpoint, convert it with `correction`")
        raise ConvertError("its `model` has no `model.init_conv.weight`: not the authors' GaussianDiffusion")
    if "ema" in ck and ck["ema"] is not None:
        ema = float_tensors(torch, entry(ck, "ema", "diffusion"), "ema.")
        if "ema.ema_model.model.init_conv.weight" not in ema:
            raise ConvertError("its `ema` has no `ema_model.model.init_conv.weight`: not an EMA of the diffusion model")
        out.update({k: v for k, v in ema.items() if not k.startswith("ema.online_model.")})
    else:
        print("convert-official: no EMA weights; pointreggpt will sample with the online ones", file=sys.stderr)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("kind", choices=KINDS, help="which of the authors' trainers wrote the checkpoint")
    ap.add_argument("checkpoint", help="the authors' .pt file (only files you trust: loading it runs pickled code)")
    ap.add_argument("output", help="the .safetensors file to write")
    args = ap.parse_args(argv)
    try:
        import torch
        from safetensors.torch import save_file
    except ImportError as e:
        sys.exit(f"convert-official: needs torch and safetensors ({e}); run scripts/install-network-peers.sh")

    try:
        ck = load_checkpoint(torch, args.checkpoint)
        tensors = (convert_correction if args.kind == "correction" else convert_diffusion)(torch, ck)
    except ConvertError as e:
        sys.exit(f"convert-official: {args.checkpoint}: {e}")

    out_dir = os.path.dirname(os.path.abspath(args.output))
    os.makedirs(out_dir, exist_ok=True)
    tmp = os.path.join(out_dir, f".{os.path.basename(args.output)}.{os.getpid()}.tmp")
    umask = os.umask(0)
    os.umask(umask)
    try:
        save_file(tensors, tmp)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, args.output)
    except Exception as e:  # noqa: BLE001
        if os.path.exists(tmp):
            os.remove(tmp)
        sys.exit(f"convert-official: {args.output}: cannot write it ({type(e).__name__}: {e})")
    params = sum(t.numel() for t in tensors.values())
    print(f"convert-official: wrote {len(tensors)} tensors ({params} values) to {args.output}")


if __name__ == "__main__":
    main()
