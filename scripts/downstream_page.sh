#!/bin/sh
# The downstream results page, docs/results/downstream-64px/: `shaderball study --downstream` on
# the serve spec (640 renders at 64 px, its own 64 spp) with a ladder of 4, 8, 16 and 32 spp, three
# training seeds a level, L1 at every level and L2 at the spec's and the cheapest passing level.
# About 2 hours on 2 cores (its estimate is printed first); killed, the same command resumes.
#
#     scripts/downstream_page.sh [STUDY_FOLDER]      # default /tmp/downstream-serve
#
# The study folder (builds, runs: ~1 GB) stays out of the repository; the page's report.md,
# downstream.json, downstream.png and the log are copied from it.
set -eu
OUT=${1:-/tmp/downstream-serve}
PAGE=docs/results/downstream-64px
mkdir -p "$PAGE"
.venv/bin/shaderball study manifests/serve.toml --downstream --out "$OUT" \
    --ladder 4,8,16,32 --repeats 3 --epochs 12 --width 0.5 --batch-size 8 --schedule cosine \
    --reference-spp 1024 2>&1 | tee -a "$OUT.log"   # -a: a resumed run adds to the log
cp "$OUT/report.md" "$OUT/downstream.json" "$OUT/downstream.png" "$PAGE/"
{
    echo "\$ scripts/downstream_page.sh $OUT    # $(nproc) cores ($(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//')), load average $(cut -d' ' -f1-3 /proc/loadavg) at the end"
    cat "$OUT.log"
} > "$PAGE/study.log"
