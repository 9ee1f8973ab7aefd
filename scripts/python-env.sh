#!/usr/bin/env bash
# Makes the project's own Python virtual environment, so that nothing the tests and benchmarks need is
# installed into the system's interpreter (an "externally managed" one, PEP 668, refuses that anyway):
# `python-env.sh [DIR]` creates DIR (default: .venv at the checkout's root) once and prints its python.
# BASE_PYTHON is the interpreter it is made from (default python3). The Makefile exports the result as
# PYTHON and puts DIR/bin first on the PATH; the install-*.sh scripts use it when PYTHON is not set.
#
# `python3 -m venv` needs ensurepip, which Debian and Ubuntu ship apart as python3-venv: as root the
# script installs that package; otherwise it makes the environment without pip and bootstraps pip from
# the wheel that the base interpreter's own pip downloads from PyPI; without either it says what to install.
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
VENV="${1:-$ROOT/.venv}"
BASE="${BASE_PYTHON:-python3}"

say() { echo "python-env: $*" >&2; }
die() {
    say "error: $*"
    exit 1
}

works() { "$VENV/bin/python" -m pip --version >/dev/null 2>&1; }

if works; then
    echo "$VENV/bin/python"
    exit 0
fi
command -v "$BASE" >/dev/null 2>&1 || die "no '$BASE' on the PATH: install Python 3.10 or newer (Debian/Ubuntu: apt-get install python3 python3-venv), or set BASE_PYTHON"
if [[ -e "$VENV" ]]; then
    say "$VENV does not work (its interpreter moved?): making it again"
    rm -rf "$VENV"
fi

made() { "$BASE" -m venv "$VENV" 2>/dev/null || { rm -rf "$VENV"; false; }; }

say "$BASE -m venv $VENV ($("$BASE" --version 2>&1))"
if ! made && [[ $(id -u) -eq 0 ]] && command -v apt-get >/dev/null 2>&1 && ! dpkg -s python3-venv >/dev/null 2>&1; then
    say "no ensurepip: apt-get install python3-venv"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q python3-venv >/dev/null ||
        { DEBIAN_FRONTEND=noninteractive apt-get update -q >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -q python3-venv >/dev/null; } ||
        die "apt-get install python3-venv failed (see apt's message above)"
    made || true
fi
if [[ ! -x "$VENV/bin/python" ]]; then
    "$BASE" -m pip --version >/dev/null 2>&1 ||
        die "$BASE can make no virtual environment with pip (no ensurepip) and has no pip of its own: as root, run \`apt-get install python3-venv\` (Debian/Ubuntu), or set BASE_PYTHON to a Python whose venv works"
    say "$BASE cannot make a venv with pip (no ensurepip): making it without, and pip from PyPI"
    "$BASE" -m venv --without-pip "$VENV" || die "$BASE -m venv --without-pip $VENV failed (see above)"
    WHEELS="$(mktemp -d)"
    trap 'rm -rf "$WHEELS"' EXIT
    "$BASE" -m pip download --disable-pip-version-check -q --no-deps --only-binary=:all: -d "$WHEELS" pip ||
        die "could not download pip from PyPI (see pip's message above)"
    wheel="$(ls "$WHEELS"/pip-*.whl)"
    "$VENV/bin/python" "$wheel/pip" install --disable-pip-version-check -q --no-index "$wheel" ||
        die "could not install pip into $VENV from $wheel"
fi
works || die "$VENV was made but its pip does not run (see above)"
echo "$VENV/bin/python"
