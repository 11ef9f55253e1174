#!/bin/bash
# `shaderball train DATASET --benchmark`: the defaults against fp32 NCHW, alternated, on the
# machine as it is and beside two busy processes (docs/neural.md, "Speed on a CPU").
# Usage: scripts/bench_train_speed.sh [DATASET]  (default /tmp/wt22b-ds)
DATASET=${1:-/tmp/wt22b-ds}
cd "$(dirname "$0")/.." || exit 1
run() { echo "== $1 | load $(cut -d' ' -f1 /proc/loadavg) | shaderball train $DATASET --benchmark $2"; .venv/bin/shaderball train $DATASET --benchmark $2 2>&1; }
for i in 1 2 3; do
  run "as is" ""
  run "as is" "--precision fp32 --no-channels-last"
done
python3 -c 'while True: pass' & B1=$!
python3 -c 'while True: pass' & B2=$!
sleep 1
for i in 1 2 3; do
  run "2 busy processes" ""
  run "2 busy processes" "--precision fp32 --no-channels-last"
  run "2 busy processes" "--threads 1"
done
kill $B1 $B2
echo "load after $(cat /proc/loadavg)"
