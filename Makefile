# pointreggpt — the commands a user runs. `make demo` and `make test` are the two in the README.
SHELL := /bin/bash
CARGO ?= cargo
PYTHON ?= python3

# Real depth sequences for the real-data tests (../shared/realdata beside the checkout, when present).
POINTREGGPT_REAL_DATA ?= $(abspath $(wildcard ../shared/realdata))
export POINTREGGPT_REAL_DATA

.PHONY: all libtorch build demo test test-deps bench bench-deps clean-libtorch help

all: build

help:
	@echo "make demo        build 240 registration pairs from embedded synthetic scenes into out/demo"
	@echo "make test        run every test (release build; real-data tests use POINTREGGPT_REAL_DATA)"
	@echo "make bench       run every benchmark against its peers and write benchmarks/REPORT.md"
	@echo "make libtorch    assemble CPU libtorch 2.13.0 from PyPI wheels into third_party/libtorch"

# libtorch from PyPI wheels (idempotent). Skipped when the user points the build elsewhere.
libtorch:
	@if [[ -n "$${LIBTORCH_USE_PYTORCH:-}" ]]; then echo "using the installed PyTorch (LIBTORCH_USE_PYTORCH)"; \
	else ./scripts/fetch-libtorch.sh; fi

build: libtorch
	$(CARGO) build --release

demo: libtorch
	$(CARGO) run --release -- build pipelines/demo.toml --out out/demo
	$(CARGO) run --release -- preview out/demo --out out/demo-preview --limit 4 --no-progress
	$(CARGO) run --release -- stats out/demo --out out/demo-stats --no-progress

# Python peers the tests compare against (pyarrow, DuckDB; PyTorch for the checkpoint conversion), from PyPI, once.
test-deps:
	./scripts/install-test-deps.sh

test: libtorch test-deps
	$(CARGO) test --release

bench-deps:
	./scripts/install-bench-peers.sh
	./scripts/install-network-peers.sh

# Every benchmark and its peers in one run; writes benchmarks/REPORT.md.
bench: libtorch bench-deps test-deps
	./scripts/bench-report.sh

clean-libtorch:
	rm -rf third_party/libtorch
