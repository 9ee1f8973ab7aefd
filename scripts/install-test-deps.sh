#!/usr/bin/env bash
# Installs what the integration tests need, pinned.
# - Python (pip): pyarrow and duckdb, which they read shards with (tests/python/read_shards.py); moto[s3]
#   with flask and flask-cors, the local S3 server tests/store.rs starts (`python3 -m moto.server`; it brings
#   boto3, which tests/python/s3_peer.py uses); azure-storage-blob, which tests/python/az_peer.py creates
#   containers and lists blobs with for tests/azure.rs; kubernetes-validate (it bundles the Kubernetes
#   schemas: tests/kubernetes.rs validates pipelines/k8s-build-job.yaml offline); and torch 2.13.0 with
#   safetensors, which tests/checkpoints.rs saves and converts the authors' kind of checkpoints with (through
#   scripts/install-network-peers.sh: PyPI's CUDA build, ~3 GB to download, 4.6 GB installed, 54 s here; it
#   runs on the CPU). open3d 0.19.0 (with Debian's libusb-1.0-0, which its import may need) is the peer of
#   tests/registration.rs (normals, FPFH, RANSAC; tests/python/open3d_registration.py): a ~450 MB wheel.
# - npm: azurite, the Azure Blob server tests/azure.rs starts (`azurite-blob`, installed globally; ~20 s
#   and ~360 MB; it needs Node.js and npm, from Debian when missing).
# - Debian (apt): slurm-wlm and munge, the one-node Slurm cluster tests/slurm.rs starts (~8 s).
#   deltalake and polars read the datasets' Delta Lake tables in tests/delta.rs (tests/python/delta_peer.py).
# - rerun-sdk, the viewer extra of the project's Python package (`pip install "./python[viewer]"`), which
#   tests/python/viewer_check.py writes an .rrd file with and reads it back.
# - Last, the project's own Python package, python/ (pointreggpt_data, checked by tests/python_package.rs),
#   with `pip install ./python`, reinstalled whenever the installed copy differs from python/.
# `make test` and .ci/run run this first.
#
# Idempotent: installs nothing that is already there (Python modules that import, Debian packages that
# are installed, azurite at the pinned version).
# The Python packages go into the project's own virtual environment: PYTHON (the Makefile sets it to
# .venv/bin/python), else the one scripts/python-env.sh makes; never into the system's interpreter.
# Without root, the Debian packages are not installed: the script says which `apt-get install` to run.
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
PYTHON="${PYTHON:-$("$ROOT/scripts/python-env.sh")}"
export PYTHON
PYARROW_VERSION="26.0.1"
DUCKDB_VERSION="2.0.0"
MOTO_VERSION="5.2.1"
FLASK_VERSION="3.1.3"
FLASK_CORS_VERSION="6.0.2"
OPEN3D_VERSION="0.19.0"
AZURE_BLOB_VERSION="12.31.1"
KUBERNETES_VALIDATE_VERSION="1.37.0"
AZURITE_VERSION="3.37.0"
DELTALAKE_VERSION="1.6.6"
POLARS_VERSION="2.1.0"
RERUN_VERSION="0.41.0"
CHECK='import pyarrow, duckdb, moto.server, flask, flask_cors, boto3, open3d, azure.storage.blob, kubernetes_validate, deltalake, polars, rerun'

die() {
    echo "install-test-deps: $*" >&2
    exit 1
}

modules_import() {
    "$PYTHON" -c "$CHECK" >/dev/null 2>&1
}

# Debian packages: `apt-get update` only when the plain install fails (stale or missing lists).
# apt_install WHY PACKAGE...
apt_install() {
    local why="$1" missing=()
    shift
    for p in "$@"; do
        dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
    done
    [[ ${#missing[@]} -eq 0 ]] && return 0
    if ! command -v apt-get >/dev/null 2>&1 || [[ $(id -u) -ne 0 ]]; then
        echo "install-test-deps: warning: not installing ${missing[*]} (needs root and apt-get): $why until you run, as root, \`apt-get install ${missing[*]}\`" >&2
        return 0
    fi
    echo "install-test-deps: apt-get install ${missing[*]}"
    if ! DEBIAN_FRONTEND=noninteractive apt-get install -y -q "${missing[@]}" >/dev/null; then
        DEBIAN_FRONTEND=noninteractive apt-get update -q >/dev/null ||
            die "apt-get update failed: is the Debian package registry reachable?"
        DEBIAN_FRONTEND=noninteractive apt-get install -y -q "${missing[@]}" >/dev/null ||
            die "apt-get install ${missing[*]} failed (see apt's message above)"
    fi
}

# Azurite from npm, pinned, installed globally (its `azurite-blob` lands on the PATH).
install_azurite() {
    if command -v azurite-blob >/dev/null 2>&1 && [[ "$(azurite-blob --version 2>/dev/null)" == "$AZURITE_VERSION" ]]; then
        return 0
    fi
    if ! command -v npm >/dev/null 2>&1; then
        apt_install "tests/azure.rs cannot start Azurite" nodejs npm
        command -v npm >/dev/null 2>&1 || die "npm is missing: install Node.js (18 or newer) and npm, then rerun"
    fi
    echo "install-test-deps: npm install -g azurite@$AZURITE_VERSION"
    npm install -g --no-audit --no-fund --loglevel=error "azurite@$AZURITE_VERSION" >/dev/null ||
        die "npm install -g azurite@$AZURITE_VERSION failed: is the npm registry reachable? (see npm's message above)"
    [[ "$(azurite-blob --version 2>/dev/null)" == "$AZURITE_VERSION" ]] ||
        die "azurite $AZURITE_VERSION was installed but \`azurite-blob --version\` does not say so (is npm's global bin, $(npm prefix -g)/bin, on the PATH?)"
}

system_deps() {
    apt_install "open3d may fail to import" libusb-1.0-0
    apt_install "tests/slurm.rs fails" slurm-wlm munge
    install_azurite
}

torch_peers() {
    PYTHON="$PYTHON" "$(dirname "$0")/install-network-peers.sh"
}

system_deps

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
    echo "install-test-deps: already installed ($("$PYTHON" -c 'import pyarrow, duckdb, importlib.metadata as m; print("pyarrow", pyarrow.__version__, "duckdb", duckdb.__version__, "moto", m.version("moto"), "open3d", m.version("open3d"), "azure-storage-blob", m.version("azure-storage-blob"), "kubernetes-validate", m.version("kubernetes-validate"), "deltalake", m.version("deltalake"), "polars", m.version("polars"))'), azurite $(azurite-blob --version 2>/dev/null), $(slurmctld -V 2>/dev/null))"
    torch_peers
    install_package
    exit 0
fi

command -v "$PYTHON" >/dev/null 2>&1 || die "no Python interpreter '$PYTHON' (set PYTHON=...)"
"$PYTHON" -m pip --version >/dev/null 2>&1 || die "'$PYTHON -m pip' does not work; install pip first"

echo "install-test-deps: $PYTHON -m pip install pyarrow==$PYARROW_VERSION duckdb==$DUCKDB_VERSION moto[s3]==$MOTO_VERSION flask==$FLASK_VERSION flask-cors==$FLASK_CORS_VERSION open3d==$OPEN3D_VERSION azure-storage-blob==$AZURE_BLOB_VERSION rerun-sdk==$RERUN_VERSION kubernetes-validate==$KUBERNETES_VALIDATE_VERSION deltalake==$DELTALAKE_VERSION polars==$POLARS_VERSION"
if ! "$PYTHON" -m pip install --disable-pip-version-check -q \
    "pyarrow==$PYARROW_VERSION" "duckdb==$DUCKDB_VERSION" "moto[s3]==$MOTO_VERSION" \
    "flask==$FLASK_VERSION" "flask-cors==$FLASK_CORS_VERSION" "open3d==$OPEN3D_VERSION" "rerun-sdk==$RERUN_VERSION" \
    "azure-storage-blob==$AZURE_BLOB_VERSION" "kubernetes-validate==$KUBERNETES_VALIDATE_VERSION" \
    "deltalake==$DELTALAKE_VERSION" "polars==$POLARS_VERSION"; then
    die "pip install failed: is PyPI reachable? (see pip's message above)"
fi

if ! modules_import; then
    "$PYTHON" -c "$CHECK" || true
    die "pyarrow, duckdb, moto, open3d, azure-storage-blob, kubernetes-validate, deltalake and polars were installed but do not import (see the error above)"
fi
torch_peers
install_package
echo "install-test-deps: done"
