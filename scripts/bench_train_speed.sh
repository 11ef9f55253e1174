#!/bin/bash
# `shaderball train DATASET --benchmark`: the defaults against fp32 NCHW, alternated, on the
# machine as it is and beside two busy processes (docs/neural.md, "Speed on a CPU").
# Usage: scripts/bench_train_speed.sh [DATASET]  (default /tmp/wt22b-ds)
refuse() { printf 'error: %s\nusage: scripts/bench_train_speed.sh [DATASET]\n' "$1" >&2; exit 2; }
[ $# -le 1 ] || refuse "at most 1 argument, $# given"
DATASET=${1:-/tmp/wt22b-ds}
[ -f "$DATASET/manifest.jsonl" ] || [ -f "$DATASET/publication.json" ] ||
  refuse "DATASET $DATASET: not a dataset folder or publication (no manifest.jsonl, publication.json)"
DATASET=$(cd "$DATASET" && pwd)
cd "$(dirname "$0")/.." || exit 1
run() { echo "== $1 | load $(cut -d' ' -f1 /proc/loadavg) | shaderball train $DATASET --benchmark $2"; .venv/bin/shaderball train $DATASET --benchmark $2 2>&1; }
for i in 1 2 3; do
  run "as is" ""
  run "as is" "--precision fp32 --no-channels-last"
done
python3 -c 'while True: pass' & B1=$!
python3 -c 'while True: pass' & B2=$!
trap 'kill $B1 $B2 2>/dev/null' EXIT
sleep 1
for i in 1 2 3; do
  run "2 busy processes" ""
  run "2 busy processes" "--precision fp32 --no-channels-last"
  run "2 busy processes" "--threads 1"
done
echo "load after $(cat /proc/loadavg)"
