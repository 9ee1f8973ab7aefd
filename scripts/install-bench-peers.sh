#!/usr/bin/env bash
# Installs the Python peers that `cargo bench --bench geometry` times against (make bench-deps).
#
# Idempotent: does nothing when the peers already import. Installs only what
# benchmarks/requirements.txt lists (numpy, scipy, pykdtree, numba, open3d, opencv-python-headless, with their own
# dependencies) plus Debian's libusb-1.0-0, which some open3d builds load at import.
# They go into the project's own virtual environment: PYTHON (the Makefile sets it to .venv/bin/python),
# else the one scripts/python-env.sh makes; never into the system's interpreter.
set -euo pipefail

cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-$(./scripts/python-env.sh)}"
REQUIREMENTS="benchmarks/requirements.txt"
CHECK='import numpy, scipy, pykdtree, numba, open3d, cv2'
VERSIONS='print("numpy", numpy.__version__, "numba", numba.__version__, "open3d", open3d.__version__)'

die() {
    echo "install-bench-peers: $*" >&2
    exit 1
}

# Prints the peers' versions when they all import; fails otherwise.
peers_import() {
    "$PYTHON" -c "$CHECK; $VERSIONS" 2>/dev/null
}

# libusb-1.0-0 from Debian: apt-get update only when the plain install fails (stale lists).
install_libusb() {
    if dpkg -s libusb-1.0-0 >/dev/null 2>&1; then
        return 0
    fi
    if ! command -v apt-get >/dev/null 2>&1 || [[ $(id -u) -ne 0 ]]; then
        echo "install-bench-peers: warning: not installing libusb-1.0-0 (needs root and apt-get): open3d may fail to import until you run, as root, \`apt-get install libusb-1.0-0\`" >&2
        return 0
    fi
    echo "install-bench-peers: apt-get install libusb-1.0-0"
    if ! DEBIAN_FRONTEND=noninteractive apt-get install -y -q libusb-1.0-0 >/dev/null; then
        DEBIAN_FRONTEND=noninteractive apt-get update -q >/dev/null ||
            die "apt-get update failed: is the Debian package registry reachable?"
        DEBIAN_FRONTEND=noninteractive apt-get install -y -q libusb-1.0-0 >/dev/null ||
            die "apt-get install libusb-1.0-0 failed"
    fi
}

install_python_peers() {
    command -v "$PYTHON" >/dev/null 2>&1 || die "no Python interpreter '$PYTHON' (set PYTHON=...)"
    "$PYTHON" -m pip --version >/dev/null 2>&1 || die "'$PYTHON -m pip' does not work; install pip first"
    echo "install-bench-peers: $PYTHON -m pip install -r $REQUIREMENTS (open3d is a ~450 MB wheel)"
    if ! "$PYTHON" -m pip install --disable-pip-version-check -q -r "$REQUIREMENTS"; then
        die "pip install -r $REQUIREMENTS failed: is PyPI reachable? (see pip's message above)"
    fi
}

if versions=$(peers_import); then
    echo "install-bench-peers: peers already installed ($versions)"
    exit 0
fi

install_libusb
install_python_peers

if ! versions=$(peers_import); then
    "$PYTHON" -c "$CHECK" || true
    die "the peers were installed but do not import (see the error above)"
fi
echo "install-bench-peers: done ($versions)"
