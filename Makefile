# pointreggpt — the commands a user runs. `make demo` and `make test` are the two in the README.
SHELL := /bin/bash
CARGO ?= cargo

# The project's own Python environment (scripts/python-env.sh): every Python package the tests and
# benchmarks use goes there, never into the system's interpreter. BASE_PYTHON is what it is made from.
BASE_PYTHON ?= python3
BASE_PATH := $(PATH)
POINTREGGPT_VENV ?= $(CURDIR)/.venv
PYTHON := $(POINTREGGPT_VENV)/bin/python
export PYTHON
export PATH := $(POINTREGGPT_VENV)/bin:$(PATH)

# Real depth frames for the real-data tests: POINTREGGPT_REAL_DATA when set, else ../shared/realdata
# beside the checkout, else fetched once from their public sources (scripts/data-sources/manifest.txt, pinned
# by SHA-256) into REALDATA_CACHE. POINTREGGPT_DATA_MIRROR=<url> fetches from a mirror instead.
POINTREGGPT_REAL_DATA ?= $(abspath $(wildcard ../shared/realdata))
REALDATA_CACHE ?= $(or $(XDG_CACHE_HOME),$(HOME)/.cache)/pointreggpt/realdata
ifeq ($(strip $(POINTREGGPT_REAL_DATA)),)
POINTREGGPT_REAL_DATA := $(REALDATA_CACHE)
REAL_DATA_FETCH := real-data
endif
export POINTREGGPT_REAL_DATA

.PHONY: all venv libtorch build demo test test-deps real-data bench bench-deps clean-libtorch help

all: build

help:
	@echo "make demo        build 240 registration pairs from embedded synthetic scenes into out/demo"
	@echo "make test        run every test (release build; real-data tests use POINTREGGPT_REAL_DATA)"
	@echo "make bench       run every benchmark against its peers and write benchmarks/REPORT.md"
	@echo "make libtorch    assemble CPU libtorch 2.13.0 from PyPI wheels into third_party/libtorch"
	@echo "make real-data   fetch the real frames the tests read into $(REALDATA_CACHE)"

venv:
	@PATH="$(BASE_PATH)" BASE_PYTHON="$(BASE_PYTHON)" ./scripts/python-env.sh "$(POINTREGGPT_VENV)" >/dev/null

# libtorch from PyPI wheels (idempotent). Skipped when the user points the build elsewhere.
libtorch: venv
	@if [[ -n "$${LIBTORCH_USE_PYTORCH:-}" ]]; then echo "using the installed PyTorch (LIBTORCH_USE_PYTORCH)"; \
	else ./scripts/fetch-libtorch.sh; fi

build: libtorch
	$(CARGO) build --release

demo: libtorch
	$(CARGO) run --release -- build pipelines/demo.toml --out out/demo
	$(CARGO) run --release -- preview out/demo --out out/demo-preview --limit 4 --no-progress
	$(CARGO) run --release -- stats out/demo --out out/demo-stats --no-progress

# Python peers the tests compare against (pyarrow, DuckDB; PyTorch for the checkpoint conversion), from PyPI, once.
test-deps: venv
	./scripts/install-test-deps.sh

real-data:
	$(BASE_PYTHON) scripts/fetch-realdata.py --dest "$(REALDATA_CACHE)"

# The integration tests are one binary (tests/suite); 3 test threads on 2 cores overlap the tests that wait
# on their servers (Azurite, moto, Slurm) with the ones that compute. Each run prints its slowest tests and
# writes every test's time to target/tmp/suite-times.tsv.
TEST_THREADS ?= 3
test: libtorch test-deps $(REAL_DATA_FETCH)
	$(CARGO) test --release -- --test-threads=$(TEST_THREADS)

bench-deps: venv
	./scripts/install-bench-peers.sh
	./scripts/install-network-peers.sh

# Every benchmark and its peers in one run; writes benchmarks/REPORT.md.
bench: libtorch bench-deps test-deps $(REAL_DATA_FETCH)
	./scripts/bench-report.sh

clean-libtorch:
	rm -rf third_party/libtorch
