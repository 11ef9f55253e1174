"""`shaderball evaluate --report DIR`: one run's evaluation as a report a reader can check.

Beside evaluate's results: scores per material class (uniform dielectric, uniform metal,
SVBRDF) with 95% intervals over the class's materials, the run's learning curve (training
and held-out loss and PSNR per epoch, from its log), and a picture grid (the maps, the
reference, the network, path tracing at equal time, and both error maps), chosen two
samples per class. Everything here is derived from the evaluation's rows and the run
folder; nothing is re-rendered.
"""

from __future__ import annotations

import io
import os

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from pipeline.image.tonemap import map_srgb8
from pipeline.neural import runfiles
from pipeline.neural.plot import learning_curve_png
from pipeline.store.atomic import write_bytes_atomic

#: A uniform material whose largest specular (F0) value is above this is a metal: the
#: dielectrics' F0 is 0.02 to 0.08 in every shipped spec, the metals' at least 0.3.
METAL_F0 = 0.1
CLASSES = ("uniform dielectric", "uniform metal", "svbrdf")
#: Report metrics with intervals (relMSE is in results.json).
METRICS = ("psnr", "ssim", "flip")
GRID_PER_CLASS = 2
#: Bootstrap resamples (over materials) of the 95% intervals; a fixed seed keeps them reproducible.
BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 0x22
#: Error maps: mean absolute 8-bit difference over RGB, times this, as a heat map.
ERROR_GAIN = 4.0


def bootstrap_ci95(values: list, groups: list, resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED):
    """Percentile 95% interval of the mean of ``values``, resampling whole ``groups`` (materials)
    with replacement; None with fewer than 2 groups or a non-finite value."""
    pairs = [(g, v) for g, v in zip(groups, values) if v is not None]
    if not pairs or not all(np.isfinite(v) for _, v in pairs):
        return None
    names = sorted({g for g, _ in pairs})
    if len(names) < 2:
        return None
    sums = np.array([sum(v for g, v in pairs if g == name) for name in names], dtype=np.float64)
    counts = np.array([sum(1 for g, _ in pairs if g == name) for name in names], dtype=np.float64)
    pick = np.random.default_rng(seed).integers(0, len(names), size=(resamples, len(names)))
    means = sums[pick].sum(axis=1) / counts[pick].sum(axis=1)
    lo, hi = np.percentile(means, [2.5, 97.5])
    return [float(lo), float(hi)]


def material_class(record: dict) -> str:
    """uniform dielectric, uniform metal (largest specular value above METAL_F0) or svbrdf."""
    material = record.get("material") or {}
    if material.get("kind") != "uniform":
        return "svbrdf"
    specular = (material.get("values") or {}).get("specular") or [0.0]
    return "uniform metal" if max(specular) > METAL_F0 else "uniform dielectric"


def class_means(rows: list[dict], methods: list[str]) -> dict:
    """{class: {method: {metric: mean, ci95: {metric: [lo, hi]}, samples, materials}}};
    intervals by :func:`bootstrap_ci95` over the class's materials."""
    out = {}
    for name in [c for c in CLASSES if any(r.get("class") == c for r in rows)]:
        members = [r for r in rows if r.get("class") == name]
        out[name] = {}
        for method in methods:
            have = [r for r in members if method in r]
            if not have:
                continue
            groups = [r["material_id"] for r in have]
            entry = {
                m: float(np.mean([r[method][m] for r in have]))
                if all(r[method].get(m) is not None for r in have)
                else None
                for m in METRICS
            }
            entry["ci95"] = {
                m: bootstrap_ci95([r[method][m] for r in have], groups) if entry[m] is not None else None
                for m in METRICS
            }
            entry["samples"] = len(have)
            entry["materials"] = len(set(groups))
            out[name][method] = entry
    return out


def _error_map(a8: np.ndarray, b8: np.ndarray) -> np.ndarray:
    e = np.abs(a8.astype(np.float32) - b8.astype(np.float32)).mean(axis=-1) / 255.0
    v = np.clip(e * ERROR_GAIN, 0.0, 1.0)
    heat = np.stack([np.clip(2 * v, 0, 1), np.clip(2 * v - 1, 0, 1), np.zeros_like(v)], axis=-1)
    return np.round(255 * heat).astype(np.uint8)


def grid_pictures(maps: np.ndarray, pictures: dict) -> dict:
    """The report grid's cells for one sample: maps (12, R, R) as pictures, the images, errors."""
    cells = {
        "diffuse": map_srgb8(np.moveaxis(maps[0:3], 0, -1)),
        "specular": map_srgb8(np.moveaxis(maps[3:6], 0, -1)),
        "roughness": map_srgb8(np.moveaxis(maps[9:12], 0, -1), srgb=False),
        "normal": map_srgb8(np.moveaxis(maps[6:9], 0, -1), srgb=False),
        "reference": pictures["reference"],
        "network": pictures["network"],
    }
    if "equal time" in pictures:
        cells["PT equal time"] = pictures["equal time"]
    for name in ("2 spp", "2 spp + OIDN"):
        if name in pictures:
            cells[name] = pictures[name]
    cells["|network - ref| x4"] = _error_map(pictures["network"], pictures["reference"])
    if "equal time" in pictures:
        cells["|PT - ref| x4"] = _error_map(pictures["equal time"], pictures["reference"])
    return cells


GRID_COLUMNS = (
    "diffuse",
    "specular",
    "roughness",
    "normal",
    "reference",
    "network",
    "PT equal time",
    "2 spp",
    "2 spp + OIDN",
    "|network - ref| x4",
    "|PT - ref| x4",
)


def picture_grid(
    rows: list[tuple[str, dict]], columns, cell_target: int = 128, label: int = 150, pad: int = 4
) -> bytes:
    """PNG bytes: a row per (title, {column: uint8 picture}), a column per name (its header),
    pictures scaled by an integer to about ``cell_target`` pixels, "left out" where missing;
    a title's lines (split on newlines) stand left of its row."""
    size = next(iter(rows[0][1].values())).shape[0]
    cell, head = size * max(1, cell_target // size), 18
    img = Image.new("RGB", (label + len(columns) * (cell + pad) + pad, head + len(rows) * (cell + pad) + pad), "white")
    draw = ImageDraw.Draw(img)
    font = ImageFont.load_default()
    for c, name in enumerate(columns):
        draw.text((label + pad + c * (cell + pad), 4), name[:22], fill="black", font=font)
    for r, (title, cells) in enumerate(rows):
        y = head + pad + r * (cell + pad)
        parts = title.split("\n")
        for k, part in enumerate(parts):
            draw.text((4, y + cell // 2 - 6 * len(parts) + 12 * k), part, fill="black", font=font)
        for c, name in enumerate(columns):
            x = label + pad + c * (cell + pad)
            if name in cells:
                img.paste(Image.fromarray(cells[name]).resize((cell, cell), Image.NEAREST), (x, y))
            else:
                draw.rectangle([x, y, x + cell, y + cell], outline="grey")
                draw.text((x + 4, y + 4), "left out", fill="grey", font=font)
    out = io.BytesIO()
    img.save(out, format="PNG")
    return out.getvalue()


def _fmt(v, spec):
    return "-" if v is None else format(v, spec)


def class_table(by_class: dict, label) -> str:
    lines = [
        "| class | method | PSNR (dB) [95%] | SSIM [95%] | HDR-FLIP [95%] | samples (materials) |",
        "|---|---|---|---|---|---|",
    ]
    for name, methods in by_class.items():
        for method, m in methods.items():
            cells = []
            for metric, spec in (("psnr", ".2f"), ("ssim", ".4f"), ("flip", ".4f")):
                ci = (m.get("ci95") or {}).get(metric)
                cells.append(
                    f"{_fmt(m[metric], spec)} [{_fmt(ci[0], spec)}, {_fmt(ci[1], spec)}]"
                    if ci
                    else _fmt(m[metric], spec)
                )
            lines.append(f"| {name} | {label(method)} | {' | '.join(cells)} | {m['samples']} ({m['materials']}) |")
    return "\n".join(lines) + "\n"


#: The files ``--report`` adds to an evaluation's folder.
REPORT_FILES = ("report.md", "report.json", "learning-curve.png", "learning-curve.csv")


def write_report(report_dir: str, result: dict, table: str, by_class_table: str, run_dir: str) -> None:
    """report.md, report.json and learning-curve.png/.csv into ``report_dir``, beside the
    evaluation's grid.png."""
    history = runfiles.read_log(run_dir)
    config = runfiles.read_config(run_dir)
    baseline = (config.get("baseline") or {}).get("test_psnr")
    options = config.get("options") or {}
    os.makedirs(report_dir, exist_ok=True)
    curve = learning_curve_png(history, baseline)
    write_bytes_atomic(os.path.join(report_dir, "learning-curve.png"), curve, inside=report_dir)
    write_bytes_atomic(os.path.join(report_dir, "learning-curve.csv"), runfiles.log_csv(history), inside=report_dir)
    last = history[-1] if history else {}
    split = config.get("split") or {}
    lines = [
        f"# Evaluation report: {os.path.basename(os.path.abspath(run_dir))}",
        "",
        (f"Written by `{result['command']}` on " if result.get("command") else "Written on ") + f"{result['date']}.",
        "",
        f"Machine: {result['machine']}.",
        "",
        f"Run: `{os.path.abspath(run_dir)}` ({config['network'].get('parameters', 0):,} parameters, width "
        f"{config['network'].get('width', 1.0)}, {config['network']['resolution']} px); trained "
        f"{last.get('epoch', 0)} epochs on {len(split.get('train', []))} materials, seed {options.get('seed')}, "
        f"lr {options.get('lr')} ({options.get('schedule', 'constant')}, warm-up {options.get('warmup_epochs', 0)} "
        f"epochs), batch {options.get('batch_size')}, loss {options.get('loss')}, precision {options.get('precision', 'fp32')}.",
        f"Evaluated on `{result['dataset']}`, split {result['split']}, checkpoint {result['checkpoint']}, "
        f"{len(result['samples'])} samples of {len({r['material_id'] for r in result['samples']})} materials.",
        "",
        "## All samples",
        "",
        table.rstrip(),
        "",
        "## Per material class",
        "",
        "95% intervals: percentile bootstrap over the class's materials (2000 resamples, fixed seed).",
        "",
        by_class_table.rstrip(),
        "",
        "## Learning curve",
        "",
        "![learning curve](learning-curve.png)",
        "",
        "Training PSNR: a fixed sample of at most 256 training renders scored in eval mode after every "
        "epoch (learning-curve.csv).",
        "",
        "## Pictures",
        "",
        "![grid](grid.png)",
        "",
        "Columns: the maps (diffuse, specular sRGB; roughness, normal colour linear), the reference, the "
        "network, path tracing at equal time and at 2 spp (and denoised), and |image - reference| on 8-bit "
        f"sRGB, mean over RGB, x{ERROR_GAIN:g}; two samples per material class.",
        "",
        *(f"- {note}" for note in result.get("notes", [])),
    ]
    text = ("\n".join(lines) + "\n").encode()
    write_bytes_atomic(os.path.join(report_dir, "report.md"), text, inside=report_dir)
    runfiles.write_json(
        os.path.join(report_dir, "report.json"),
        {
            **result,
            "history": history,
            "run_options": options,
            "run_split": config.get("split"),
            "baseline": config.get("baseline"),
        },
        inside=report_dir,
    )
