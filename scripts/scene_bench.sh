#!/bin/sh
# A build's overhead over bare renders on the four built-in objects under two 4096 x 2048
# environment maps (the shipped studio and outdoor maps, made again at that size by
# scripts/make_environments.py), at the paper's 400 px and 150 spp: `shaderball bench` on
# 4 materials x 3 lightings, in this process. About 4 minutes on 2 cores; run it on an idle
# machine (the render calls slow down under load, the build's own costs do not).
#
#     scripts/scene_bench.sh [WORK_FOLDER]      # default /tmp/scene-bench
set -eu
[ $# -le 1 ] || { echo "error: at most one argument (WORK_FOLDER), $# given" >&2; echo "usage: scripts/scene_bench.sh [WORK_FOLDER]" >&2; exit 2; }
OUT=${1:-/tmp/scene-bench}
mkdir -p "$OUT"
.venv/bin/python scripts/make_environments.py --out "$OUT/maps" --height 2048
cat > "$OUT/spec.toml" <<'SPEC'
[dataset]
name = "scene-bench"
seed = 5
materials = 4
lights_per_material = 3
shard_size = 1

[materials]
texture_resolution = 256

[scene]
objects = ["sphere", "torus", "rounded_cube", "shaderball"]
scheme = "cycle"

[lighting]
source = "environment"
environments = ["maps"]

[render]
resolution = 400
spp = 150
SPEC
.venv/bin/python -m cli bench "$OUT/spec.toml" --workers 0 --json-out "$OUT/bench.json"
