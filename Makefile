# Two entry points (see README): `make demo` and `make test`. Both do all set-up
# on a fresh Debian 12 machine: libLLVM 19 for drjit, a virtual environment, packages.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
DEMO_OUT ?= demo-out
PIP_VERSION   := 26.3
TORCH_VERSION := 2.13.0
UV_VERSION    := 0.13.9

.PHONY: setup llvm slurm chromium demo test lint test-all bench clean lock serve-network

setup: llvm $(STAMP)

# drjit 1.5 crashes with Debian's libLLVM 15; install 19 unless a usable one exists.
llvm:
	@$(PYTHON) scripts/ensure_llvm.py

# The real-SLURM tests (tests/test_slurm_real.py) need Debian's slurm-wlm and munge: installed
# as root with apt-get where possible; anywhere else a note, and those tests are skipped.
slurm:
	@$(PYTHON) scripts/ensure_optional.py slurm

# The browser test of `shaderball serve` (tests/test_serve_browser.py) needs Debian's chromium:
# installed as root with apt-get where possible; anywhere else a note, and that test is skipped.
chromium:
	@$(PYTHON) scripts/ensure_optional.py chromium

# Installs exactly what requirements.lock pins, each file checked against its SHA-256 (the
# versions CI tested); then torch, pinned to this machine's local CPU wheel where it lies (an
# unpinned torch pulls gigabytes of CUDA packages; PyPI's 2.13.0 elsewhere); then the package
# itself, editable, with no further dependency. `pip check` proves nothing is missing.
$(STAMP): pyproject.toml requirements.lock
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check 'pip==$(PIP_VERSION)'
	$(PY) -m pip install -q --require-hashes --no-deps -r requirements.lock
	$(PY) -m pip install -q --no-deps 'torch==$(TORCH_VERSION)'
	$(PY) -m pip install -q --no-deps --no-build-isolation -e .
	$(PY) -m pip check
	touch $(STAMP)

# Re-resolve requirements.lock from pyproject.toml and requirements.in (newest versions the
# ranges allow), with hashes for every platform; review the diff, run `make test`, commit.
lock:
	$(PYTHON) -m venv .lock-venv
	.lock-venv/bin/python -m pip install -q 'uv==$(UV_VERSION)'
	.lock-venv/bin/uv pip compile pyproject.toml requirements.in --extra dev --universal \
		--python-version 3.11 --generate-hashes --no-header -o .lock-venv/body.txt
	@{ awk '/^[^#]/ {exit} {print}' requirements.lock; cat .lock-venv/body.txt; } > requirements.lock.new
	mv requirements.lock.new requirements.lock
	rm -rf .lock-venv

demo: setup
	$(VENV)/bin/shaderball build manifests/smoke.toml --out $(DEMO_OUT)/smoke
	$(VENV)/bin/shaderball validate $(DEMO_OUT)/smoke --fast
	$(VENV)/bin/shaderball preview $(DEMO_OUT)/smoke --out $(DEMO_OUT)/smoke-preview.png
	@echo
	@echo "demo: dataset in $(DEMO_OUT)/smoke (manifest.jsonl, shards/), contact sheet $(DEMO_OUT)/smoke-preview.png"

test: setup slurm chromium
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(PY) -m pytest -q -n 2 tests

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

# The network `shaderball serve --run serve-out/run` shows out of the box (docs/serve.md): the
# serve spec (128 materials x 5 suns at 64 px, 64 spp; about 1.5 minutes on 2 cores), then a
# half-width network with a cosine schedule, in the precision and threads train picks for the
# machine, for as many epochs (at most 60) as fit what the build left of SERVE_MINUTES (less
# 45 s for train's start-up and the last epoch's ups and downs); train's last lines print the
# held-out PSNR beside the mean image's.
SERVE_OUT ?= serve-out
SERVE_MINUTES ?= 15
serve-network: setup
	start=$$(date +%s); set -e; \
	$(VENV)/bin/shaderball build manifests/serve.toml --out $(SERVE_OUT)/serve; \
	left=$$(( $(SERVE_MINUTES) * 60 - 45 - $$(date +%s) + start )); [ $$left -ge 60 ] || left=60; \
	$(VENV)/bin/shaderball train $(SERVE_OUT)/serve --out $(SERVE_OUT)/run --epochs 60 \
		--minutes $$(awk "BEGIN { print $$left / 60 }") --loss l1 --width 0.5 --schedule cosine --batch-size 8 --seed 0; \
	echo "serve-network: $$(( $$(date +%s) - start )) s wall, $$(nproc) cores ($$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//')), load average $$(cut -d' ' -f1-3 /proc/loadavg) at the end"; \
	echo "serve-network: run \`$(VENV)/bin/shaderball serve --run $(SERVE_OUT)/run --dataset $(SERVE_OUT)/serve\`"

bench: setup
	$(VENV)/bin/shaderball bench manifests/smoke.toml

clean:
	rm -rf $(VENV) $(DEMO_OUT) $(SERVE_OUT)
