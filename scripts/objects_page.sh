#!/bin/sh
# The objects results page, docs/results/objects-64px/: does the paper's network carry over to an
# object it never saw, and do the geometry buffers help? A dataset on the 4 built-in objects
# (shaderball, sphere, rounded_cube, torus; scheme "cycle": one object per material; 96 materials x
# 3 suns = 288 renders, 64 px, 16 spp, storage.layers with geometry_normal and depth), the torus held
# out of training (--held-out-objects torus; the other objects' materials split 80/20 by material,
# split seed 0), a small network (width 0.25, L1, 12 epochs, cosine) trained with 3 seeds without and
# with --geometry, each evaluated on its test split (seen objects' held-out materials, and every
# torus material). About 15 minutes on 2 cores; the work folder stays out of the repository.
#
#     scripts/objects_page.sh [WORK_FOLDER]      # default /tmp/objects-page
set -eu
OUT=${1:-/tmp/objects-page}
PAGE=docs/results/objects-64px
SEEDS="0 1 2"
EPOCHS=12
mkdir -p "$OUT" "$PAGE"
cat > "$OUT/spec.toml" <<'EOF'
[dataset]
name = "objects-64px"
version = "1"
seed = 2019
materials = 96
lights_per_material = 3
svbrdf_fraction = 0.5
shard_size = 16

[materials]
texture_resolution = 64

[lighting]
elevation_deg = [5.0, 90.0]
azimuth_deg = [0.0, 360.0]
turbidity = [1.0, 10.0]

[render]
resolution = 64
spp = 16
variant = "llvm_ad_rgb"

[scene]
objects = ["shaderball", "sphere", "rounded_cube", "torus"]
scheme = "cycle"

[storage]
layers = ["diffuse", "specular", "roughness", "normal", "mask", "geometry_normal", "depth"]
texture_maps = true
EOF
started=$(date +%s)
.venv/bin/shaderball build "$OUT/spec.toml" --out "$OUT/dataset" --workers 2 2>&1 | tail -3
for geometry in off on; do
    for seed in $SEEDS; do
        run="$OUT/runs/geometry-$geometry-seed$seed"
        flag=""
        [ "$geometry" = on ] && flag="--geometry"
        .venv/bin/shaderball train "$OUT/dataset" --out "$run" $flag --held-out-objects torus --split-seed 0 \
            --seed "$seed" --epochs "$EPOCHS" --width 0.25 --batch-size 8 --loss l1 --lr 2e-3 \
            --schedule cosine --precision fp32 2>&1 | tail -2
        .venv/bin/shaderball evaluate "$run" "$OUT/dataset" --spp none --no-flip --overwrite \
            --json-out "$run/objects-results.json" > /dev/null
    done
done
elapsed=$(( $(date +%s) - started ))
MACHINE="$(nproc) cores ($(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//')), load average $(cut -d' ' -f1-3 /proc/loadavg) at the end"
.venv/bin/python - "$OUT" "$PAGE" "$SEEDS" "$elapsed" "$MACHINE" "$EPOCHS" <<'EOF'
"""Seed-level summary: per group (seen objects' held-out materials; the held-out torus), the
network's relMSE against the mean image (paired ratio) and its PSNR minus the mean image's, and
geometry against none, each with a 95% interval from the crossed bootstrap over materials' samples
and seeds (pipeline.study.stats.paired_ratio, shared_seeds: a seed is one trained network)."""
import json
import os
import sys

from pipeline.image.chart import BLUE, GREY, RED, chart, png
from pipeline.study.stats import paired_ratio

out, page, seeds, elapsed, machine = sys.argv[1], sys.argv[2], sys.argv[3].split(), int(sys.argv[4]), sys.argv[5]
epochs = sys.argv[6]
GROUPS = ("seen", "held-out")
CONFIGS = ("off", "on")


def load(geometry, seed):
    with open(os.path.join(out, "runs", f"geometry-{geometry}-seed{seed}", "objects-results.json")) as f:
        return json.load(f)


results = {(g, s): load(g, s) for g in CONFIGS for s in seeds}


def per_sample(geometry, group, method, metric):
    """sample id -> [value per seed] of the group's samples."""
    values = {}
    for seed in seeds:
        for row in results[(geometry, seed)]["samples"]:
            if row.get("object_group") == group and method in row:
                values.setdefault(row["id"], []).append(row[method][metric])
    return values


summary = {"groups": {}, "command": "scripts/objects_page.sh " + out, "machine": machine, "seconds": elapsed}
for group in GROUPS:
    entry = {}
    mean = per_sample("off", group, "mean_image", "relmse")
    mean_psnr = per_sample("off", group, "mean_image", "psnr")
    for geometry in CONFIGS:
        net = per_sample(geometry, group, "network", "relmse")
        net_psnr = per_sample(geometry, group, "network", "psnr")
        entry[f"geometry_{geometry}"] = {
            "samples": len(net),
            "relmse_vs_mean_image": paired_ratio(net, mean, shared_seeds=True).to_dict(),
            "psnr_minus_mean_image": paired_ratio(net_psnr, mean_psnr, ratio=False, shared_seeds=True).to_dict(),
        }
    on, off = per_sample("on", group, "network", "relmse"), per_sample("off", group, "network", "relmse")
    entry["relmse_geometry_vs_none"] = paired_ratio(on, off, shared_seeds=True).to_dict()
    on_p, off_p = per_sample("on", group, "network", "psnr"), per_sample("off", group, "network", "psnr")
    entry["psnr_geometry_minus_none"] = paired_ratio(on_p, off_p, ratio=False, shared_seeds=True).to_dict()
    entry["mean_image_psnr"] = sum(v[0] for v in mean_psnr.values()) / len(mean_psnr)
    entry["network_psnr"] = {
        g: sum(sum(v) / len(v) for v in per_sample(g, group, "network", "psnr").values()) / len(mean_psnr)
        for g in CONFIGS
    }
    summary["groups"][group] = entry
summary["runs"] = {
    f"geometry-{g}-seed{s}": {
        "by_object": {k: v["network"]["psnr"] for k, v in results[(g, s)]["by_object"].items()},
        "parameters": json.load(open(os.path.join(out, "runs", f"geometry-{g}-seed{s}", "config.json")))["network"][
            "parameters"
        ],
    }
    for g in CONFIGS
    for s in seeds
}


def iv(d, spec=".3f"):
    return f"{d['value']:{spec}} [{d['lo']:{spec}}, {d['hi']:{spec}}]"


lines = [
    "# Objects: seen against a held-out object, with and without the geometry buffers (64 px, CPU scale)",
    "",
    f"```\n$ {summary['command']}    # {machine}; {elapsed // 60} min {elapsed % 60} s\n```",
    "",
    "Dataset: 96 materials (half uniform, half SVBRDF) x 3 suns = 288 renders at 64x64, 16 spp, on the 4 "
    "built-in objects in turn (scheme \"cycle\": 24 materials each), geometry_normal and depth stored. "
    "Training: the torus held out (`--held-out-objects torus`), the other 72 materials split 80/20 by "
    f"material (split seed 0: 58 train, 14 test), width 0.25, L1, lr 2e-3 cosine, {epochs} epochs, batch 8, "
    f"seeds {', '.join(seeds)}; without and with `--geometry`. Evaluated on the test split: 'seen' = the "
    "seen objects' held-out materials (42 samples), 'held-out' = every torus material (72 samples).",
    "",
    "95% intervals: crossed bootstrap over samples and the 3 seeds (pipeline.study.stats.paired_ratio, "
    "shared_seeds); relMSE as a ratio to the training-set mean image (below 1: better than the mean image), "
    "PSNR as a difference in dB.",
    "",
    "| group | geometry | network PSNR (dB) | PSNR - mean image (dB) [95%] | relMSE / mean image [95%] |",
    "|---|---|---|---|---|",
]
for group in GROUPS:
    e = summary["groups"][group]
    for g in CONFIGS:
        c = e[f"geometry_{g}"]
        lines.append(
            f"| {group} | {g} | {e['network_psnr'][g]:.2f} | {iv(c['psnr_minus_mean_image'], '.2f')} | "
            f"{iv(c['relmse_vs_mean_image'])} |"
        )
    lines.append(f"| {group} | mean image | {e['mean_image_psnr']:.2f} | - | - |")
lines += [
    "",
    "Geometry against none (same samples, same seeds):",
    "",
    "| group | PSNR with - without (dB) [95%] | relMSE with / without [95%] |",
    "|---|---|---|",
]
for group in GROUPS:
    e = summary["groups"][group]
    lines.append(f"| {group} | {iv(e['psnr_geometry_minus_none'], '.2f')} | {iv(e['relmse_geometry_vs_none'])} |")


def said(d, better_if_above, unit):
    """Whether an interval says better, worse, or cannot tell."""
    lo, hi = d["lo"], d["hi"]
    if (lo > 0 if better_if_above else hi < 1):
        return f"better ({iv(d, unit)})"
    if (hi < 0 if better_if_above else lo > 1):
        return f"worse ({iv(d, unit)})"
    return f"not distinguishable ({iv(d, unit)})"


verdict = []
for group in GROUPS:
    e = summary["groups"][group]
    for g in CONFIGS:
        c = e[f"geometry_{g}"]
        verdict.append(
            f"- {group} objects, geometry {g}: against the mean image, PSNR "
            f"{said(c['psnr_minus_mean_image'], True, '.2f')} dB; relMSE {said(c['relmse_vs_mean_image'], False, '.3f')}."
        )
    verdict.append(
        f"- {group} objects, geometry against none: PSNR {said(e['psnr_geometry_minus_none'], True, '.2f')} dB; "
        f"relMSE {said(e['relmse_geometry_vs_none'], False, '.3f')}."
    )
summary["verdict"] = verdict
lines += ["", "![PSNR by group](objects.png)", "", "## Verdict (from the intervals above)", "", *verdict, ""]
series = []
# each configuration a little apart from the other at its group, so their intervals do not overlap
for label, colour, key, shift in (("no geometry", BLUE, "off", -0.04), ("--geometry", RED, "on", 0.04)):
    points = []
    for x, group in enumerate(GROUPS, start=1):
        d = summary["groups"][group][f"geometry_{key}"]["psnr_minus_mean_image"]
        points.append((x + shift, d["value"], d["lo"], d["hi"]))
    series.append((label, colour, points))
series.append(("--mean image", GREY, [(1, 0.0), (2, 0.0)]))
picture = png(chart(series, "network PSNR - mean image PSNR (dB), 95% intervals", "group: 1 seen objects, 2 the held-out torus"))
with open(os.path.join(page, "objects.png"), "wb") as f:
    f.write(picture)
with open(os.path.join(page, "objects.json"), "w") as f:
    json.dump(summary, f, indent=2, sort_keys=True)
    f.write("\n")
with open(os.path.join(page, "report.md"), "w") as f:
    f.write("\n".join(lines))
print("\n".join(lines))
EOF
