#!/usr/bin/env bash
# Do two checkouts make the same outputs? Each builds manifests/smoke.toml, publishes it and runs a
# tiny study, with the renderer's clock fixed (records hold render times); then the SHA-256 of every
# file is compared. Study rows, study.json, report.md and pareto.png hold timings and differ anyway.
#   scripts/same_outputs.sh CHECKOUT_A CHECKOUT_B OUT      (each checkout with its .venv)
set -euo pipefail
refuse() { printf 'error: %s\nusage: scripts/same_outputs.sh CHECKOUT_A CHECKOUT_B OUT\n' "$1" >&2; exit 2; }
# Every argument is checked before anything is written or removed: OUT/A and OUT/B are rebuilt.
[ $# -eq 3 ] || refuse "3 arguments expected, $# given"
for repo in "$1" "$2"; do
  [ -f "$repo/cli.py" ] && [ -f "$repo/manifests/smoke.toml" ] || refuse "$repo: not a shaderball checkout (no cli.py, manifests/smoke.toml)"
  [ -x "$repo/.venv/bin/python" ] || refuse "$repo: no .venv/bin/python (each checkout with its .venv)"
done
[ ! -e "$3" ] || [ -d "$3" ] || refuse "OUT $3: exists and is not a folder"
for side in A B; do
  o="$3/$side"
  [ ! -e "$o" ] || [ -f "$o/digests.txt" ] || [ -f "$o/build.log" ] || [ -z "$(ls -A "$o" 2>/dev/null)" ] ||
    refuse "OUT $3: $side holds files this script did not write (no build.log); it would be removed: name another OUT"
done
here=$(cd "$(dirname "$0")" && pwd)
out=$(mkdir -p "$3" && cd "$3" && pwd)
for side in A B; do
  repo=$([ $side = A ] && echo "$1" || echo "$2"); o="$out/$side"; rm -rf "$o"; mkdir -p "$o"
  ( cd "$repo"; export PYTHONPATH="$here/fixed_clock"
    .venv/bin/python -m cli build manifests/smoke.toml --out "$o/smoke" > "$o/build.log" 2>&1
    .venv/bin/python -m cli publish "$o/smoke" --out "$o/pub" > "$o/pub.log" 2>&1
    .venv/bin/python -m cli study manifests/smoke.toml --out "$o/study" --resolution 16 --configs ladder \
      --ladder 4 --reference-spp 64 --repeats 1 --no-flip > "$o/study.log" 2>&1 )
  ( cd "$o"; find smoke pub study -type f ! -name '*.lock' | sort | xargs sha256sum > digests.txt )
done
for part in smoke pub study; do
  same=$(join -j 2 <(grep " $part/" "$out/A/digests.txt" | sort -k2) <(grep " $part/" "$out/B/digests.txt" | sort -k2) | awk '$2==$3' | wc -l)
  all=$(grep -c " $part/" "$out/A/digests.txt")
  echo "$part: $same of $all files byte-identical"
  join -j 2 <(grep " $part/" "$out/A/digests.txt" | sort -k2) <(grep " $part/" "$out/B/digests.txt" | sort -k2) | awk '$2!=$3 {print "  differs: " $1}'
done
