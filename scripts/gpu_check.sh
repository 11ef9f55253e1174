#!/usr/bin/env bash
# Device checks of the multi-GPU build, about 3 minutes on one GPU: the paper spec cut to
# 50 renders built by one worker pinned to GPU 0 and by two workers sharing it; the outputs must be
# identical, and both rates are recorded. Run by ../shared/gpu/check.sh with $OUT (logs) and $SB (a
# `shaderball` command); by hand: OUT=/tmp/out SB="python -m cli" bash scripts/gpu_check.sh
set -u
out=${OUT:-/tmp/out}; sb=${SB:-shaderball}; mkdir -p "$out"
spec=/tmp/gpu-check.toml
# 50 renders at the paper's settings: its first materials only (a smaller dataset.size).
sed -E 's/^(materials|count|size) *= *[0-9_]+/\1 = 10/' manifests/paper.toml > "$spec"
rc=0
for w in 1 2; do
  rm -rf "/tmp/gpu-check-w$w"
  start=$(date +%s.%N)
  timeout 80 $sb build "$spec" --out "/tmp/gpu-check-w$w" --gpus 0, --workers $w > "$out/build-w$w.log" 2>&1 || rc=1
  end=$(date +%s.%N)
  n=$(find "/tmp/gpu-check-w$w/shards" -name 'm*_l*.json' 2>/dev/null | wc -l)
  echo "workers=$w on GPU 0: $n renders in $(echo "$end - $start" | bc) s; $(grep -o 'renders per GPU.*' "$out/build-w$w.log" | head -1)" | tee -a "$out/rates.txt"
done
# Identical outputs: every EXR (renders and maps), byte for byte; records and markers hold each
# render's time, so they differ between any two builds and are left out.
if diff -r -q -x '*.json' -x '*.lock' /tmp/gpu-check-w1/shards /tmp/gpu-check-w2/shards > "$out/diff.txt" 2>&1; then
  echo "identical: 1 worker and 2 workers on one GPU" | tee -a "$out/rates.txt"
else
  echo "DIFFERENT: see diff.txt" | tee -a "$out/rates.txt"; rc=1
fi
exit $rc
