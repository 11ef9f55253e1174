#!/usr/bin/env bash
# Device checks of the multi-GPU build, about 3 minutes on one GPU: the paper spec cut to
# 50 renders built by one worker pinned to GPU 0 and by two workers sharing it; the outputs must be
# identical, and both rates are recorded. Run by ../shared/gpu/check.sh with $OUT (logs) and $SB (a
# `shaderball` command); by hand: OUT=/tmp/out SB="python -m cli" bash scripts/gpu_check.sh
set -u
refuse() { printf 'error: %s\nusage: OUT=DIR SB=COMMAND bash scripts/gpu_check.sh   (from the repository root)\n' "$1" >&2; exit 2; }
out=${OUT:-/tmp/out}; sb=${SB:-shaderball}
[ $# -eq 0 ] || refuse "no arguments (OUT and SB come from the environment), $# given"
[ -f manifests/paper.toml ] || refuse "no manifests/paper.toml here: run it from the repository root"
[ ! -e "$out" ] || [ -d "$out" ] || refuse "OUT $out: exists and is not a folder"
command -v ${sb%% *} > /dev/null || refuse "SB $sb: not a command"
mkdir -p "$out"
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
# DistributedDataParallel with one device (nccl, SyncBatchNorm, one spawned process) against the
# one-process path on the 1-worker build: the first epoch's training loss within 2e-2 relative
# (Adam turns float noise into lr-sized steps: tests/test_neural_distributed.py), and both rates.
timeout 90 python3 -c '
import shutil, sys, torch
from pipeline.neural.config import TrainConfig
from pipeline.neural.distributed import train_distributed
from pipeline.neural.train import train
def config(name):
    shutil.rmtree(f"/tmp/gpu-check-{name}", ignore_errors=True)
    return TrainConfig(dataset="/tmp/gpu-check-w1", out=f"/tmp/gpu-check-{name}", epochs=1, loss="l1",
                       resolution=64, device="cuda").check()
one = train(config("train-one"))
ddp = train_distributed(config("train-ddp"), None, None, torch.device("cuda"))
la, lb = one.history[0]["train_loss"], ddp.history[0]["train_loss"]
ra, rb = one.history[0]["samples_per_s"], ddp.history[0]["samples_per_s"]
rel = abs(la - lb) / la
print(f"train, DDP with one device ({ddp.device}): loss {lb:.6f} against one process {la:.6f} "
      f"(relative {rel:.1e}); {rb:.1f} against {ra:.1f} samples/s")
sys.exit(0 if rel < 2e-2 else 1)
' > "$out/ddp.log" 2>&1 || rc=1
tail -1 "$out/ddp.log" | tee -a "$out/rates.txt"
exit $rc
