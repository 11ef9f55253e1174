# Two entry points (see README): `make demo` and `make test`. Both do all set-up
# on a fresh Debian 12 machine: libLLVM 19 for drjit, a virtual environment, packages.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
DEMO_OUT ?= demo-out

.PHONY: setup llvm slurm demo test lint test-all bench clean

setup: llvm $(STAMP)

# drjit 1.5 crashes with Debian's libLLVM 15; install 19 unless a usable one exists.
llvm:
	@$(PYTHON) scripts/ensure_llvm.py

# The real-SLURM tests (tests/test_slurm_real.py) need Debian's slurm-wlm and munge: installed
# as root with apt-get where possible; anywhere else a note, and those tests are skipped.
slurm:
	@$(PYTHON) scripts/ensure_slurm.py

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	@# torch first, pinned to this machine's local CPU wheel (an unpinned torch pulls gigabytes
	@# of CUDA packages); then the train extra (torch>=2.4,<3, already met) for the neural stage.
	@if [ -f /opt/wheels/torch-2.13.0+cpu-cp311-cp311-manylinux_2_28_x86_64.whl ] || [ -n "$$SHADERBALL_TORCH" ]; then \
		$(PY) -m pip install -q 'torch==2.13.0'; fi
	$(PY) -m pip install -q -e '.[dev,train]'
	touch $(STAMP)

demo: setup
	$(VENV)/bin/shaderball build manifests/smoke.toml --out $(DEMO_OUT)/smoke
	$(VENV)/bin/shaderball validate $(DEMO_OUT)/smoke --fast
	$(VENV)/bin/shaderball preview $(DEMO_OUT)/smoke --out $(DEMO_OUT)/smoke-preview.png
	@echo
	@echo "demo: dataset in $(DEMO_OUT)/smoke (manifest.jsonl, shards/), contact sheet $(DEMO_OUT)/smoke-preview.png"

test: setup slurm
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(PY) -m pytest -q -n 2 tests

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

bench: setup
	$(VENV)/bin/shaderball bench manifests/smoke.toml

clean:
	rm -rf $(VENV) $(DEMO_OUT)
