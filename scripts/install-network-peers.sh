#!/usr/bin/env bash
# Installs the PyTorch peer that `cargo bench --bench networks` times our networks against
# (benchmarks/peers/networks_peers.py): torch 2.13.0 (the release our libtorch is) and safetensors,
# from PyPI. `make bench-deps` calls this.
#
# Idempotent: does nothing when `import torch, safetensors` already works with torch 2.13.x.
# PyPI's torch 2.13.0 is the CUDA build: with its nvidia-* dependencies it is a ~3 GB download, and it
# runs on the CPU when there is no GPU. The torch wheel that scripts/fetch-libtorch.sh keeps in
# third_party/wheels (the same release) is installed when it fits this Python, saving ~0.9 GB of the
# download; its CUDA dependencies come from pip's cache or PyPI. Without torch the benchmark still runs
# and prints ours, with the peer marked unavailable.
# They go into the project's own virtual environment: PYTHON (the Makefile sets it to .venv/bin/python),
# else the one scripts/python-env.sh makes; never into the system's interpreter.
set -euo pipefail

cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-$(./scripts/python-env.sh)}"
TORCH_VERSION="2.13.0"
SAFETENSORS_VERSION="0.8.0"
NUMPY_VERSION="2.2.6" # torch warns at import without numpy; the pin matches benchmarks/requirements.txt
WHEELS="third_party/wheels"
CHECK='import torch, safetensors; assert torch.__version__.startswith("'"${TORCH_VERSION%.*}"'."), torch.__version__'
VERSIONS='import torch, safetensors; print("torch", torch.__version__, "safetensors", safetensors.__version__)'

die() {
    echo "install-network-peers: $*" >&2
    exit 1
}

peers_import() {
    "$PYTHON" -c "$CHECK" >/dev/null 2>&1
}

if peers_import; then
    echo "install-network-peers: already installed ($("$PYTHON" -c "$VERSIONS" 2>/dev/null))"
    exit 0
fi

command -v "$PYTHON" >/dev/null 2>&1 || die "no Python interpreter '$PYTHON' (set PYTHON=...)"
"$PYTHON" -m pip --version >/dev/null 2>&1 || die "'$PYTHON -m pip' does not work; install pip first"

PIP=("$PYTHON" -m pip install --disable-pip-version-check -q)
# The wheel fetch-libtorch.sh downloaded, when its tags fit this interpreter (pip refuses it otherwise).
shopt -s nullglob
local_wheels=("$WHEELS"/torch-"$TORCH_VERSION"-*.whl)
shopt -u nullglob
if [[ ${#local_wheels[@]} -gt 0 ]] &&
    echo "install-network-peers: $PYTHON -m pip install ${local_wheels[0]} safetensors==$SAFETENSORS_VERSION numpy==$NUMPY_VERSION (torch's CUDA libraries ~2 GB)" &&
    "${PIP[@]}" "${local_wheels[0]}" "safetensors==$SAFETENSORS_VERSION" "numpy==$NUMPY_VERSION"; then
    :
else
    echo "install-network-peers: $PYTHON -m pip install torch==$TORCH_VERSION safetensors==$SAFETENSORS_VERSION numpy==$NUMPY_VERSION (~3 GB with torch's CUDA libraries)"
    "${PIP[@]}" "torch==$TORCH_VERSION" "safetensors==$SAFETENSORS_VERSION" "numpy==$NUMPY_VERSION" ||
        die "pip install torch==$TORCH_VERSION failed (see pip's message above): is PyPI reachable?"
fi

if ! peers_import; then
    "$PYTHON" -c "$CHECK" || true
    die "torch and safetensors were installed but do not import (see the error above)"
fi
echo "install-network-peers: done ($("$PYTHON" -c "$VERSIONS" 2>/dev/null))"
