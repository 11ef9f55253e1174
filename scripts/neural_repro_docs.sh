#!/usr/bin/env bash
# Copies what scripts/neural_repro.sh and scripts/neural_default_check.sh wrote into
# docs/results/neural-mini/ (the reports docs/neural.md quotes; tests/test_neural_docs.py checks that
# every table row it quotes is in them).
#
#   scripts/neural_repro_docs.sh [OUT] [DEFAULT_OUT]   (defaults: /tmp/neural-repro, /tmp/neural-default-check)
set -euo pipefail
refuse() { printf 'error: %s\nusage: scripts/neural_repro_docs.sh [OUT] [DEFAULT_OUT]\n' "$1" >&2; exit 2; }
[ $# -le 2 ] || refuse "at most 2 arguments, $# given"
cd "$(dirname "$0")/.."
OUT=${1:-/tmp/neural-repro}
DEFAULT_OUT=${2:-/tmp/neural-default-check}
DOCS=docs/results/neural-mini
# The docs folder is replaced: only once OUT holds what is copied into it.
for f in "$OUT/sweep/sweep.md" "$OUT/sweep/data-size.png"; do
  [ -f "$f" ] || refuse "OUT $OUT: no ${f#"$OUT/"} (scripts/neural_repro.sh writes it); $DOCS left as it is"
done
[ ! -e "$DEFAULT_OUT" ] || [ -d "$DEFAULT_OUT" ] || refuse "DEFAULT_OUT $DEFAULT_OUT: not a folder"
rm -rf "$DOCS"
mkdir -p "$DOCS/sweep"
cp "$OUT/sweep/sweep.md" "$OUT/sweep/data-size.png" "$DOCS/sweep/"
for report in "$OUT"/run-*/report "$OUT"/run-*/report-all; do
  [[ -d "$report" ]] || continue
  dest="$DOCS/$(basename "$(dirname "$report")")/$(basename "$report")"
  mkdir -p "$dest"
  cp "$report/report.md" "$report/learning-curve.png" "$report/learning-curve.csv" "$dest/"
  # the pictures of the evaluation with path tracing only (the others' grids leave it out)
  if [[ "$(basename "$report")" == report ]]; then cp "$report/grid.png" "$dest/"; fi
done
[[ -f "$OUT/repro.log" ]] && cp "$OUT/repro.log" "$DOCS/repro.log"
if [[ -f "$DEFAULT_OUT/train.json" ]]; then
  cp "$DEFAULT_OUT/train.json" "$DOCS/default-check-train.json"
  cp "$DEFAULT_OUT/check.log" "$DOCS/default-check.log"
fi
ls -R "$DOCS"
