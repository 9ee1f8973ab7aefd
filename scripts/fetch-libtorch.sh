#!/usr/bin/env bash
# Assemble a CPU libtorch 2.13.0 from PyPI wheels into third_party/libtorch (see ../shared/ARCHITECTURE.md).
# Idempotent: does nothing when third_party/libtorch/build-version already says 2.13.0.
set -euo pipefail

TORCH_VERSION=2.13.0
CUDART_VERSION=13.0.96
CUPTI_VERSION=13.0.85
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
DEST="$ROOT/third_party/libtorch"
PYTHON="${PYTHON:-python3}"

if [[ -f "$DEST/build-version" && "$(cat "$DEST/build-version")" == "$TORCH_VERSION" && -e "$DEST/lib/libtorch.so" ]]; then
  echo "libtorch $TORCH_VERSION already assembled in $DEST"
  exit 0
fi

WHEELS="$ROOT/third_party/wheels"
mkdir -p "$WHEELS"
echo "downloading torch==$TORCH_VERSION and the CUDA runtime wheels from PyPI (once; pip caches them)..."
if ! "$PYTHON" -m pip download --quiet --no-deps --only-binary=:all: -d "$WHEELS" \
      "torch==$TORCH_VERSION" \
      "nvidia-cuda-runtime==$CUDART_VERSION" \
      "nvidia-cuda-cupti==$CUPTI_VERSION"; then
  echo "error: pip could not download torch==$TORCH_VERSION / nvidia-cuda-runtime==$CUDART_VERSION /" >&2
  echo "       nvidia-cuda-cupti==$CUPTI_VERSION from the package registry." >&2
  echo "       Check that PyPI is reachable (pip config, proxy), or point LIBTORCH at an existing libtorch" >&2
  echo "       2.13.0, or set LIBTORCH_USE_PYTORCH=1 to use an installed PyTorch (see README)." >&2
  exit 1
fi

STAGE="$(mktemp -d "$ROOT/third_party/.libtorch-stage.XXXXXX")"
trap 'rm -rf "$STAGE"' EXIT
unzip_member() { # wheel, pattern, out-dir
  "$PYTHON" - "$1" "$2" "$3" <<'PY'
import sys, zipfile, fnmatch
wheel, pattern, out = sys.argv[1:4]
with zipfile.ZipFile(wheel) as z:
    names = [n for n in z.namelist() if fnmatch.fnmatch(n, pattern)]
    if not names:
        sys.exit(f"error: {wheel} has no member matching {pattern}")
    for n in names:
        z.extract(n, out)
PY
}

TORCH_WHL=$(ls "$WHEELS"/torch-"$TORCH_VERSION"-*.whl | head -n1)
CUDART_WHL=$(ls "$WHEELS"/nvidia_cuda_runtime*-"$CUDART_VERSION"-*.whl | head -n1)
CUPTI_WHL=$(ls "$WHEELS"/nvidia_cuda_cupti*-"$CUPTI_VERSION"-*.whl | head -n1)

unzip_member "$TORCH_WHL" 'torch/include/*' "$STAGE"
unzip_member "$TORCH_WHL" 'torch/share/*' "$STAGE"
for lib in libtorch_cpu.so libc10.so libgomp.so.1 libshm.so libtorch_global_deps.so; do
  unzip_member "$TORCH_WHL" "torch/lib/$lib" "$STAGE"
done
unzip_member "$CUDART_WHL" '*/libcudart.so.13' "$STAGE/cudart"
unzip_member "$CUPTI_WHL" '*/libcupti.so.13' "$STAGE/cupti"

OUT="$STAGE/libtorch"
mkdir -p "$OUT/lib"
mv "$STAGE/torch/include" "$STAGE/torch/share" "$OUT/"
mv "$STAGE"/torch/lib/* "$OUT/lib/"
find "$STAGE/cudart" "$STAGE/cupti" -name 'lib*.so.13' -exec mv {} "$OUT/lib/" \;
ln -sf libtorch_cpu.so "$OUT/lib/libtorch.so"
echo "$TORCH_VERSION" > "$OUT/build-version"

rm -rf "$DEST"
mv "$OUT" "$DEST"
echo "libtorch $TORCH_VERSION assembled in $DEST"
