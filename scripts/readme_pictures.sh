#!/usr/bin/env bash
# Regenerates every picture the README shows, each with the command that draws it:
#
#   docs/img/smoke_preview.png    the demo's contact sheet: `make demo`'s build and preview
#                                 commands (manifests/smoke.toml, 16 renders)
#   docs/img/network_vs_pt.png    the network next to path tracing: `shaderball evaluate --report`'s
#                                 grid, after a short training run on manifests/train-small.toml
#                                 (120 renders at 64x64; a half-width network, 30 epochs)
#   docs/img/accuracy_time.png    error against CPU time: `shaderball study`'s pareto.png, a small
#                                 study of manifests/smoke.toml (the spp ladder and denoising)
#   docs/img/scenes.png           one material on the four built-in objects under the two shipped
#                                 environment maps: `shaderball figures scenes` (8 renders)
#
#   scripts/readme_pictures.sh [WORK]   (default WORK: out/readme-pictures; its folders are
#                                        rebuilt, so the pictures come from fresh runs)
#
# 14 minutes of wall time (5.4 CPU-minutes) on the shared 2-core machine here, beside other work:
# the two builds about a minute, training and evaluation most of the rest, the study 3.4 minutes.
set -euo pipefail
refuse() { printf 'error: %s\nusage: scripts/readme_pictures.sh [WORK]\n' "$1" >&2; exit 2; }
[ $# -le 1 ] || refuse "at most 1 argument, $# given"
cd "$(dirname "$0")/.."
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
SB=${SHADERBALL:-.venv/bin/shaderball}
WORK=${1:-out/readme-pictures}
command -v "$SB" > /dev/null || refuse "SHADERBALL $SB: not a command"
# WORK is removed and rebuilt: only when it holds nothing but what this script writes there.
if [ -e "$WORK" ] || [ -L "$WORK" ]; then
  [ -d "$WORK" ] && [ ! -L "$WORK" ] || refuse "WORK $WORK: exists and is not a folder"
  for entry in "$WORK"/* "$WORK"/.[!.]*; do
    [ -e "$entry" ] || [ -L "$entry" ] || continue
    case "${entry##*/}" in
      smoke | train-small | run | study) ;;
      *) refuse "WORK $WORK: holds ${entry##*/}, which this script does not write; WORK is removed: name another" ;;
    esac
  done
fi
rm -rf "$WORK"
mkdir -p "$WORK" docs/img
start=$SECONDS
step() { echo "== $* ($((SECONDS - start)) s)" >&2; }

step "the demo's contact sheet"
"$SB" build manifests/smoke.toml --out "$WORK/smoke"
"$SB" preview "$WORK/smoke" --out docs/img/smoke_preview.png

step "the network next to path tracing"
"$SB" build manifests/train-small.toml --out "$WORK/train-small"
"$SB" train "$WORK/train-small" --out "$WORK/run" --epochs 30 --width 0.5 --loss l1 --lr 2e-3 \
  --schedule cosine --batch-size 6 --threads 1 --seed 0
"$SB" evaluate "$WORK/run" "$WORK/train-small" --report --no-flip
cp "$WORK/run/evaluation-test/grid.png" docs/img/network_vs_pt.png

step "the accuracy/time plot"
"$SB" study manifests/smoke.toml --out "$WORK/study" --configs ladder,denoise --reference-spp 256 \
  --ladder 1,2,4,8,16,32,64 --no-flip
cp "$WORK/study/pareto.png" docs/img/accuracy_time.png

step "the objects under the environment maps"
"$SB" figures scenes --out docs/img/scenes.png

step "done: docs/img/smoke_preview.png, docs/img/network_vs_pt.png, docs/img/accuracy_time.png, docs/img/scenes.png"
