#!/usr/bin/env bash
# Why the CPU-scale reproduction trains at 64x64 with --width 0.5 (docs/neural.md, "A
# CPU-scale reproduction"): `shaderball train --benchmark` on the mini dataset at widths 1,
# 0.5 and 0.25 (one and two torch threads), and the training step at 64 and 128 pixels
# (`python -m pipeline.neural.bench train-options`, widths alternated, 3 repeats).
#
#   scripts/neural_bench_widths.sh MINI_DATASET [OUT_FILE]
set -euo pipefail
cd "$(dirname "$0")/.."
MINI=${1:?usage: scripts/neural_bench_widths.sh MINI_DATASET [OUT_FILE]}
OUT_FILE=${2:-/dev/stdout}
SB=${SHADERBALL:-.venv/bin/shaderball}
PY=${PYTHON:-.venv/bin/python}
{
  for threads in 1 2; do
    for width in 1 0.5 0.25; do
      echo "== load $(cut -d' ' -f1 /proc/loadavg) | shaderball train MINI --benchmark --loss l1 --width $width --threads $threads"
      "$SB" train "$MINI" --benchmark --loss l1 --width "$width" --threads "$threads"
    done
  done
  for resolution in 64 128; do
    echo "== load $(cut -d' ' -f1 /proc/loadavg) | python -m pipeline.neural.bench train-options --resolution $resolution --loss l1 --threads 1 --repeats 3 --variants 'baseline,--width 0.5,--width 0.25'"
    "$PY" -m pipeline.neural.bench train-options --resolution "$resolution" --loss l1 --threads 1 --repeats 3 \
      --variants "baseline,--width 0.5,--width 0.25" |
      "$PY" -c 'import json,sys; d=json.load(sys.stdin); [print(f"{r[\"options\"]}: {r[\"samples_per_s_median\"]:.2f} samples/s (median of {d[\"repeats\"]}; all {r[\"samples_per_s_all\"]})") for r in d["rows"]]'
  done
  echo "== load $(cut -d' ' -f1 /proc/loadavg) | done"
} >"$OUT_FILE" 2>&1
