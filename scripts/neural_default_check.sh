#!/usr/bin/env bash
# A check of train's defaults: `manifests/smoke.toml` with 64 materials (128 renders at
# 64x64, 16 spp), `shaderball train` with every default but --loss l1 (no VGG16 ImageNet
# weights here) and --threads 1 (speed only: two torch threads beside other work collapse;
# docs/neural.md, "Speed on a CPU"), then the last epoch's held-out PSNR against the training
# set's mean image.
#
#   scripts/neural_default_check.sh [OUT]      (default OUT: /tmp/neural-default-check)
set -euo pipefail
refuse() { printf 'error: %s\nusage: scripts/neural_default_check.sh [OUT]\n' "$1" >&2; exit 2; }
[ $# -le 1 ] || refuse "at most 1 argument, $# given"
cd "$(dirname "$0")/.."
OUT=${1:-/tmp/neural-default-check}
SB=${SHADERBALL:-.venv/bin/shaderball}
[ ! -e "$OUT" ] || [ -d "$OUT" ] || refuse "OUT $OUT: exists and is not a folder"
command -v "$SB" > /dev/null || refuse "SHADERBALL $SB: not a command"
mkdir -p "$OUT"
exec > >(tee "$OUT/check.log") 2>&1
sed 's/^materials = 8 .*/materials = 64/' manifests/smoke.toml >"$OUT/smoke64.toml"
grep -q '^materials = 64$' "$OUT/smoke64.toml"
"$SB" build "$OUT/smoke64.toml" --out "$OUT/smoke64" --workers 0 2>&1 | tail -n 1
/usr/bin/time -f "train wall %e s" "$SB" train "$OUT/smoke64" --out "$OUT/run" --loss l1 --threads 1 --json >"$OUT/train.json"
python3 - "$OUT/train.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
last = s["history"][-1]
margin = last["test_psnr"] - s["baseline_psnr"]
print(f"epochs {last['epoch']}: held-out PSNR {last['test_psnr']:.2f} dB, mean image {s['baseline_psnr']:.2f} dB, "
      f"margin {margin:+.2f} dB ({'more' if margin > 1 else 'NOT more'} than 1 dB)")
PY
