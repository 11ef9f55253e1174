#!/usr/bin/env bash
# The CPU-scale reproduction of the paper's experiment (docs/neural.md, "A CPU-scale
# reproduction"): builds manifests/mini.toml, trains the recipe on three training-set sizes
# (nested subsets of the training materials, one held-out set) with two seeds, evaluates
# every run with a report, and writes the data-size sweep. Re-running continues: builds and
# training resume, a finished run's report is kept.
#
#   scripts/neural_repro.sh [OUT]          (default OUT: /tmp/neural-repro)
#
# Two runs train at a time, one torch thread each (on a 2-core machine one thread per run
# does not collapse under other load; docs/neural.md, "Speed on a CPU"). Every size gets the
# same number of optimiser steps (epochs x training renders is constant), so the sizes differ
# in data only.
set -euo pipefail
refuse() { printf 'error: %s\nusage: scripts/neural_repro.sh [OUT]\n' "$1" >&2; exit 2; }
[ $# -le 1 ] || refuse "at most 1 argument, $# given"
cd "$(dirname "$0")/.."
OUT=${1:-/tmp/neural-repro}
SB=${SHADERBALL:-.venv/bin/shaderball}
[ ! -e "$OUT" ] || [ -d "$OUT" ] || refuse "OUT $OUT: exists and is not a folder"
command -v "$SB" > /dev/null || refuse "SHADERBALL $SB: not a command"
mkdir -p "$OUT"
# The recipe (docs/neural.md): the paper's L1 term (no VGG16 ImageNet weights here), Adam at
# the released code's 1e-3 with a cosine decay, half the paper's channels, batch 6.
RECIPE=(--loss l1 --width 0.5 --lr 1e-3 --schedule cosine --batch-size 6 --test-fraction 0.1 --split-seed 0 --threads 1)
# training materials : epochs : warm-up epochs (the same steps for every size)
SIZES=(${SIZES:-576:10:0.5 288:20:1 144:40:2 72:80:4})
SEEDS=(${SEEDS:-1 2})

log() { printf '== %s | load %s | %s\n' "$(date -u +%H:%M:%S)" "$(cut -d' ' -f1 /proc/loadavg)" "$*"; }

log "build manifests/mini.toml"
/usr/bin/time -f "build wall %e s" "$SB" build manifests/mini.toml --out "$OUT/mini" --workers 0 2>&1 | tail -n 3

train_one() {  # size epochs warmup seed
  local run="$OUT/run-m$1-s$4"
  log "train $run"
  "$SB" train "$OUT/mini" --out "$run" "${RECIPE[@]}" --train-materials "$1" --epochs "$2" --warmup-epochs "$3" \
    --seed "$4" >"$run.log" 2>&1
  tail -n 3 "$run.log"
}

jobs_=()
for size in "${SIZES[@]}"; do
  IFS=: read -r m e w <<<"$size"
  for seed in "${SEEDS[@]}"; do jobs_+=("$m $e $w $seed"); done
done
for ((i = 0; i < ${#jobs_[@]}; i += 2)); do
  train_one ${jobs_[i]} &
  if ((i + 1 < ${#jobs_[@]})); then train_one ${jobs_[i + 1]} & fi
  wait
done

reports=()
for size in "${SIZES[@]}"; do
  IFS=: read -r m e w <<<"$size"
  for seed in "${SEEDS[@]}"; do
    run="$OUT/run-m$m-s$seed"
    # every run on all held-out samples, without path tracing and HDR-FLIP (most of an
    # evaluation's time at 64x64): the network, the mean image, the nearest sample, for the sweep
    reports+=("$run/report-all/report.json")
    if [[ ! -f "$run/report-all/report.json" ]]; then
      log "evaluate $run --spp none --no-flip"
      "$SB" evaluate "$run" "$OUT/mini" --out "$run/report-all" --report \
        --spp none --no-flip 2>&1 | grep -v ' samples .* ETA ' | tail -n 12
    fi
    # path tracing once (1 and 4 spp and equal time, with and without OIDN, every metric), beside
    # the first size's first seed, on the first 160 held-out samples (32 materials): it does not
    # depend on the run (the equal-time spp follows the network's width, the same for every run)
    if [[ "$size" == "${SIZES[0]}" && "$seed" == "${SEEDS[0]}" && ! -f "$run/report/report.json" ]]; then
      log "evaluate $run --spp 1,4 --limit 160"
      "$SB" evaluate "$run" "$OUT/mini" --out "$run/report" --report --spp 1,4 --limit 160 2>&1 | grep -v ' samples .* ETA ' | tail -n 30
    fi
  done
done
log "sweep"
"$SB" sweep "${reports[@]}" --out "$OUT/sweep"
log "done"
