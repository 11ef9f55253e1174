#!/usr/bin/env bash
# The README's test command on a fresh clone, with two CPU-bound processes beside it:
# clones HEAD of this checkout into a scratch folder, starts two busy loops, runs .ci/run there
# and prints its exit code, wall time and pytest's summary line; the whole log goes to LOG.
#   scripts/suite_under_load.sh [LOG]      (default: suite-under-load.log)
set -uo pipefail
refuse() { printf 'error: %s\nusage: scripts/suite_under_load.sh [LOG]\n' "$1" >&2; exit 2; }
[ $# -le 1 ] || refuse "at most 1 argument, $# given"
repo="$(cd "$(dirname "$0")/.." && pwd)"
log="$(realpath -m "${1:-suite-under-load.log}")"
[ -d "$(dirname "$log")" ] || refuse "LOG $log: its folder does not exist"
[ ! -d "$log" ] || refuse "LOG $log: is a folder"
scratch="$(mktemp -d)"
git clone -q "$repo" "$scratch/clone" || exit 1
cd "$scratch/clone" || exit 1
python3 -c 'while True: pass' & b1=$!
python3 -c 'while True: pass' & b2=$!
trap 'kill $b1 $b2 2>/dev/null' EXIT
# pytest lists its 25 slowest steps in the log; the slowest is printed below: pytest-timeout
# stops a test at 900 s (pyproject.toml), and on a busy machine no test should come near that.
export PYTEST_ADDOPTS="${PYTEST_ADDOPTS:-} --durations=25"
start=$(date +%s)
./.ci/run > "$log" 2>&1
rc=$?
wall=$(( $(date +%s) - start ))
summary=$(grep -E '^[0-9]+ (passed|failed)|^=+ .*(passed|failed)' "$log" | tail -1)
echo "commit $(git rev-parse --short HEAD): exit $rc, wall ${wall} s ($(( wall / 60 ))m$(( wall % 60 ))s) with two busy processes beside it; load average $(cut -d' ' -f1-3 /proc/loadavg); $summary" | tee -a "$log"
slowest=$(awk '/slowest [0-9]+ durations/ {on = 1; next} on && /^[0-9.]+s (setup|call|teardown) / {print; exit}' "$log" | tr -s ' ')
echo "slowest step: ${slowest:-none listed} (pytest's timeout: 900 s a test)" | tee -a "$log"
rm -rf "$scratch"
exit $rc
