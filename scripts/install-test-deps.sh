#!/usr/bin/env bash
# Installs the Python modules the integration tests need, pinned: pyarrow and duckdb, which they read shards
# with (tests/python/read_shards.py); moto[s3] with flask and flask-cors, the local S3 server tests/store.rs
# starts (`python3 -m moto.server`; it brings boto3, which tests/python/s3_peer.py uses); and torch 2.13.0
# with safetensors, which tests/checkpoints.rs saves and converts the authors' kind of checkpoints with (through scripts/install-network-peers.sh: PyPI's CUDA
# build, ~3 GB to download, 4.6 GB installed, 54 s here; it runs on the CPU). `make test` and .ci/run run
# this first. open3d 0.19.0 (with Debian's libusb-1.0-0, which its import may need) is the peer of
# tests/registration.rs (normals, FPFH, RANSAC; tests/python/open3d_registration.py): a ~450 MB wheel.
# Last, the project's own Python package, python/ (pointreggpt_data, checked by tests/python_package.rs),
# with `pip install ./python`, reinstalled whenever the installed copy differs from python/.
#
# Idempotent: installs nothing that already imports.
# PYTHON selects the interpreter (default python3).
set -euo pipefail

PYTHON="${PYTHON:-python3}"
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
PYARROW_VERSION="26.0.1"
DUCKDB_VERSION="2.0.0"
MOTO_VERSION="5.2.1"
FLASK_VERSION="3.1.3"
FLASK_CORS_VERSION="6.0.2"
OPEN3D_VERSION="0.19.0"
CHECK='import pyarrow, duckdb, moto.server, flask, flask_cors, boto3, open3d'

die() {
    echo "install-test-deps: $*" >&2
    exit 1
}

modules_import() {
    "$PYTHON" -c "$CHECK" >/dev/null 2>&1
}

# libusb-1.0-0 from Debian (open3d loads it at import on some builds): apt-get update only when the
# plain install fails (stale lists).
install_libusb() {
    if dpkg -s libusb-1.0-0 >/dev/null 2>&1; then
        return 0
    fi
    if ! command -v apt-get >/dev/null 2>&1 || [[ $(id -u) -ne 0 ]]; then
        echo "install-test-deps: warning: cannot install libusb-1.0-0 (needs root and apt-get); open3d may fail to import" >&2
        return 0
    fi
    echo "install-test-deps: apt-get install libusb-1.0-0"
    if ! DEBIAN_FRONTEND=noninteractive apt-get install -y -q libusb-1.0-0 >/dev/null; then
        DEBIAN_FRONTEND=noninteractive apt-get update -q >/dev/null ||
            die "apt-get update failed: is the Debian package registry reachable?"
        DEBIAN_FRONTEND=noninteractive apt-get install -y -q libusb-1.0-0 >/dev/null ||
            die "apt-get install libusb-1.0-0 failed"
    fi
}

torch_peers() {
    PYTHON="$PYTHON" "$(dirname "$0")/install-network-peers.sh"
}

# Whether the installed pointreggpt_data has exactly the files of python/pointreggpt_data (run outside
# the checkout, so that the import finds the installed copy).
package_current() {
    (cd / && "$PYTHON" - "$ROOT/python/pointreggpt_data" >/dev/null 2>&1) <<'PY'
import filecmp, os, sys
import pointreggpt_data
source, installed = sys.argv[1], os.path.dirname(pointreggpt_data.__file__)
names = [n for n in os.listdir(source) if n.endswith(".py")]
same = all(os.path.exists(os.path.join(installed, n)) and filecmp.cmp(os.path.join(source, n), os.path.join(installed, n), shallow=False) for n in names)
sys.exit(0 if names and same else 1)
PY
}

install_package() {
    if package_current; then
        echo "install-test-deps: pointreggpt_data (python/) already installed"
        return 0
    fi
    echo "install-test-deps: $PYTHON -m pip install ./python (pointreggpt_data)"
    "$PYTHON" -m pip install --disable-pip-version-check -q --no-deps --force-reinstall "$ROOT/python" ||
        die "pip install ./python failed (see pip's message above; building it needs setuptools from PyPI)"
    rm -rf "$ROOT/python/build" "$ROOT/python/"*.egg-info
    package_current || die "pointreggpt_data was installed but does not import, or differs from python/"
}

if modules_import; then
    echo "install-test-deps: already installed ($("$PYTHON" -c 'import pyarrow, duckdb, importlib.metadata as m; print("pyarrow", pyarrow.__version__, "duckdb", duckdb.__version__, "moto", m.version("moto"), "open3d", m.version("open3d"))'))"
    torch_peers
    install_package
    exit 0
fi

command -v "$PYTHON" >/dev/null 2>&1 || die "no Python interpreter '$PYTHON' (set PYTHON=...)"
"$PYTHON" -m pip --version >/dev/null 2>&1 || die "'$PYTHON -m pip' does not work; install pip first"

install_libusb
echo "install-test-deps: $PYTHON -m pip install pyarrow==$PYARROW_VERSION duckdb==$DUCKDB_VERSION moto[s3]==$MOTO_VERSION flask==$FLASK_VERSION flask-cors==$FLASK_CORS_VERSION open3d==$OPEN3D_VERSION"
if ! "$PYTHON" -m pip install --disable-pip-version-check -q \
    "pyarrow==$PYARROW_VERSION" "duckdb==$DUCKDB_VERSION" "moto[s3]==$MOTO_VERSION" \
    "flask==$FLASK_VERSION" "flask-cors==$FLASK_CORS_VERSION" "open3d==$OPEN3D_VERSION"; then
    die "pip install failed: is PyPI reachable? (see pip's message above)"
fi

if ! modules_import; then
    "$PYTHON" -c "$CHECK" || true
    die "pyarrow, duckdb, moto and open3d were installed but do not import (see the error above)"
fi
torch_peers
install_package
echo "install-test-deps: done"
