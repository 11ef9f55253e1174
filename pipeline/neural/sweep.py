"""Runs of several training-set sizes and seeds, side by side: the data-size curve.

``shaderball sweep`` (:func:`write_sweep`, a :class:`pipeline.neural.config.SweepRequest`) reads the report.json that
`shaderball evaluate --report` wrote for each run (all evaluated on the same held-out
samples) and writes into its ``out`` folder:

- ``sweep.md``: per training size and seed, the network's held-out PSNR with its 95%
  interval, the paired differences network - mean image and network - nearest sample (per
  sample, then bootstrapped over materials: a difference whose interval lies above 0 is a
  win beyond noise), and the seeds pooled (each material's mean over the seeds);
- ``sweep.json``: the same numbers;
- ``data-size.png``: held-out PSNR against the number of training renders (log axis), each
  seed with its interval, the baselines dashed.

Which runs belong together is checked: the same held-out samples, the same dataset.
"""

from __future__ import annotations

import datetime
import json
import math
import os
import platform
import re

import numpy as np

from pipeline.errors import ShaderballError
from pipeline.fields import FieldError
from pipeline.neural import plot, runfiles
from pipeline.neural.config import SweepRequest
from pipeline.neural.limits import INTEGER_RANGES
from pipeline.neural.report import bootstrap_ci95
from pipeline.store.atomic import write_bytes_atomic
from pipeline.store.bounded_read import read_bytes
from pipeline.store.record_fields import json_type_name, short_json

BASELINES = ("mean_image", "nearest_sample")
SEED_COLOURS = (plot.BLUE, plot.RED, plot.GREEN, plot.PURPLE, plot.ORANGE)


#: Largest report.json read: evaluate writes ~3.3 kB a held-out sample (the smoke dataset with
#: path tracing and the denoiser), so this holds ~20,000 (the paper's 5,000 held-out renders
#: make ~17 MB). A larger file is refused before a byte of it is read.
MAX_REPORT_BYTES = 64 << 20
#: Bytes of a report per JSON array or object, and per value (``,`` and ``:``), at least, past
#: an allowance: evaluate writes ~110-150 and ~13-20 (compact or indented). Parsing a report
#: costs ~3 times its size; a text of bare brackets would cost ~30 times, which this bounds.
BYTES_PER_CONTAINER, BYTES_PER_VALUE = 32, 8
STRUCTURE_ALLOWANCE = 4096
#: The deepest nesting of arrays and objects a report.json may have (one holds 4 levels): checked
#: before parsing, since how deep json.loads goes before RecursionError depends on the process's
#: recursion limit, which other libraries raise.
MAX_REPORT_DEPTH = 32
_JSON_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"')

NUMBER, PAIR = "a finite number", "null or an array of two finite numbers"
#: Every field of a report sweep reads: (dotted name, kind, required); a field not required
#: may be absent or null. Then of each method of ``mean`` it reads (METHOD_FIELDS), of the
#: last epoch of ``history`` (EPOCH_FIELDS) and of each of ``samples`` (ROW_FIELDS).
REPORT_FIELDS = (
    ("samples", list, True),
    ("run_options", dict, True),
    ("run_options.seed", int, False),
    ("run_options.train_materials", int, False),
    ("run_split", dict, False),
    ("run_split.train", list, False),
    ("train_renders", int, False),
    ("history", list, False),
    ("mean", dict, True),
    ("mean.network", dict, True),
)
METHOD_FIELDS = (("psnr", NUMBER, True), ("ci95", dict, True), ("ci95.psnr", PAIR, False))
#: The methods of ``mean`` read besides the network, and what each adds.
MEAN_METHODS = {"mean_image": (), "nearest_sample": (), "pt_equal_time": (("spp", NUMBER, True),)}
MEAN_METHODS["pt_equal_time+oidn"] = MEAN_METHODS["pt_equal_time"]
ROW_FIELDS = (("id", str, True), ("material_id", str, True), ("network", dict, True), ("network.psnr", NUMBER, True))
EPOCH_FIELDS = (("epoch", int, True), ("train_psnr", NUMBER, False))
#: Integers sweep reads, and their ranges (a run's own: pipeline.neural.limits).
INTEGER_FIELD_RANGES = {
    "run_options.seed": INTEGER_RANGES["seed"],
    "run_options.train_materials": (0, 10**12),
    "train_renders": (0, 10**12),
    "epoch": (0, INTEGER_RANGES["epochs"][1]),
}
_KINDS = {dict: "an object", list: "an array", str: "a string", int: "an integer"}


def _refused(path: str, what: str) -> FieldError:
    """``path``, one of the command's reports, refused: ``what`` is wrong with it."""
    return SweepRequest.field_error(
        "reports", path, "a report.json that `shaderball evaluate --report` wrote", what=f"{path}: {what}"
    )


def _load(path: str) -> dict:
    """A report.json, read bounded (:data:`MAX_REPORT_BYTES`, its JSON structure counted before it
    is parsed) and every field sweep uses checked (:func:`report_problem`); a
    :class:`~pipeline.fields.FieldError` of ``reports`` naming the file and the field if not."""
    try:
        data = read_bytes(path, MAX_REPORT_BYTES)
    except OSError as exc:
        raise _refused(path, f"cannot be read ({exc.strerror or exc})") from None
    containers, values = data.count(b"[") + data.count(b"{"), data.count(b",") + data.count(b":")
    if (containers - STRUCTURE_ALLOWANCE) * BYTES_PER_CONTAINER > len(data) or (
        values - STRUCTURE_ALLOWANCE
    ) * BYTES_PER_VALUE > len(data):
        raise _refused(
            path,
            f"{containers} JSON arrays/objects and {values} values in {len(data)} bytes, more than a report "
            f"holds (one per {BYTES_PER_CONTAINER} and {BYTES_PER_VALUE} bytes): not parsed",
        )
    depth = _nesting(data)
    if depth > MAX_REPORT_DEPTH:
        raise _refused(path, f"arrays/objects nested {depth} deep, more than a report's {MAX_REPORT_DEPTH}: not parsed")
    try:
        doc = json.loads(data)
    except (ValueError, RecursionError) as exc:  # UnicodeDecodeError is a ValueError
        raise _refused(path, f"not JSON ({type(exc).__name__}: {str(exc)[:80]})") from None
    problem = report_problem(doc)
    if problem:
        raise _refused(path, problem)
    return doc


def _nesting(data: bytes) -> int:
    """How deep ``data``'s arrays and objects nest, strings left out (their brackets are text)."""
    bare = np.frombuffer(_JSON_STRING.sub(b"", data), dtype=np.uint8)
    steps = np.isin(bare, (ord("["), ord("{"))).astype(np.int64) - np.isin(bare, (ord("]"), ord("}")))
    return int(np.cumsum(steps).max(initial=0))


def _finite(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _type_problem(name: str, value, kind) -> str | None:
    """Why ``value`` (of the field ``name``) is not of ``kind`` (a JSON type, NUMBER or PAIR)."""
    if kind == NUMBER:
        ok = _finite(value)
    elif kind == PAIR:
        ok = value is None or (isinstance(value, list) and len(value) == 2 and all(map(_finite, value)))
    else:
        ok = isinstance(value, kind) and not isinstance(value, bool)
    if not ok:
        shown = "" if value is None else f" ({short_json(value)})"
        return f"{name} is {json_type_name(value)}{shown}, not {_KINDS.get(kind, kind)}"
    low, high = INTEGER_FIELD_RANGES.get(name.rpartition("].")[2], (None, None))
    if kind is int and low is not None and not low <= value <= high:
        return f"{name} is {short_json(value)}, not in [{low}, {high}]"
    return None


def _fields_problem(obj: dict, fields, prefix: str = "") -> str | None:
    """The first of ``fields`` ((dotted name, kind, required)) of ``obj`` that is absent (or
    null) where required, or not of its kind; names are shown after ``prefix``."""
    for field, kind, required in fields:
        value, parts = obj, field.split(".")
        for part in parts:
            value = value.get(part) if isinstance(value, dict) else None
        if value is None:
            if required:
                return f"no {prefix}{field} (a report of `shaderball evaluate --report` has one)"
            continue
        problem = _type_problem(prefix + field, value, kind)
        if problem:
            return problem
    return None


def report_problem(doc) -> str | None:
    """The first field sweep reads (:data:`REPORT_FIELDS`) that a report lacks, or holds as
    another type or as a number that is not finite (NaN, an infinity), named as
    ``samples[3].network.psnr``; None when every one can be used."""
    if not isinstance(doc, dict):
        return f"not a JSON object ({json_type_name(doc)})"
    problem = _fields_problem(doc, REPORT_FIELDS)
    for method, extra in (("network", ()), *MEAN_METHODS.items()):
        if problem is None and method in doc["mean"]:
            problem = _type_problem(f"mean.{method}", doc["mean"][method], dict) or _fields_problem(
                doc["mean"][method], (*METHOD_FIELDS, *extra), f"mean.{method}."
            )
    if problem is None and doc.get("history"):
        epoch = doc["history"][-1]
        problem = _type_problem("history[-1]", epoch, dict) or _fields_problem(epoch, EPOCH_FIELDS, "history[-1].")
    if problem is None and not doc["samples"]:
        return "samples is an empty array (a report holds one sample or more)"
    for index, row in enumerate(doc["samples"] if problem is None else ()):
        where = f"samples[{index}]"
        problem = _type_problem(where, row, dict) or _fields_problem(row, ROW_FIELDS, f"{where}.")
        for baseline in BASELINES:
            if problem is None and baseline in row:
                problem = _type_problem(f"{where}.{baseline}", row[baseline], dict) or _fields_problem(
                    row[baseline], (("psnr", NUMBER, True),), f"{where}.{baseline}."
                )
        if problem:
            break
    return problem


def _paired(rows: list[dict], a: str, b: str, metric: str = "psnr"):
    have = [r for r in rows if a in r and b in r]
    if not have:
        return None, None
    diff = [r[a][metric] - r[b][metric] for r in have]
    return float(np.mean(diff)), bootstrap_ci95(diff, [r["material_id"] for r in have])


def summarise(docs: list[tuple[str, dict]]) -> dict:
    """One entry per (training renders, seed), sorted; the seeds pooled per size."""
    ids = {tuple(sorted(r["id"] for r in d["samples"])) for _, d in docs}
    if len(ids) != 1:
        raise ShaderballError(
            "the reports were evaluated on different samples; a sweep compares runs on one held-out set"
        )
    entries = []
    for path, d in docs:
        rows = d["samples"]
        history = d.get("history") or []
        train_renders = d.get("train_renders")
        entry = {
            "report": os.path.abspath(path),
            "seed": d["run_options"].get("seed"),
            "train_materials": len((d.get("run_split") or {}).get("train") or [])
            or d["run_options"].get("train_materials"),
            "train_renders": train_renders,
            "epochs": history[-1]["epoch"] if history else None,
            "network": {"psnr": d["mean"]["network"]["psnr"], "ci95": d["mean"]["network"]["ci95"].get("psnr")},
            "train_psnr": history[-1].get("train_psnr") if history else None,
        }
        for b in BASELINES:
            if b in d["mean"]:
                entry[b] = {"psnr": d["mean"][b]["psnr"], "ci95": d["mean"][b]["ci95"].get("psnr")}
                mean, ci = _paired(rows, "network", b)
                entry[f"network_minus_{b}"] = {"psnr": mean, "ci95": ci}
        for pt in ("pt_equal_time", "pt_equal_time+oidn"):
            if pt in d["mean"]:
                entry[pt] = {
                    "psnr": d["mean"][pt]["psnr"],
                    "ci95": d["mean"][pt]["ci95"].get("psnr"),
                    "spp": d["mean"][pt].get("spp"),
                }
        entries.append(entry)
    pooled = [
        _pool(size, [d for _, d in docs if (d.get("train_renders") or 0) == size])
        for size in sorted({e["train_renders"] or 0 for e in entries})
    ]
    entries.sort(key=lambda e: (e["train_renders"] or 0, e["seed"] or 0))
    return {"runs": entries, "pooled": pooled}


def _pool(size: int, group: list[dict]) -> dict:
    """Each sample's network PSNR averaged over the seeds, then the mean and its interval over
    materials; the same for the differences with the baselines."""
    by_id: dict[str, list[dict]] = {}
    for d in group:
        for r in d["samples"]:
            by_id.setdefault(r["id"], []).append(r)
    ids = sorted(by_id)
    groups = [by_id[i][0]["material_id"] for i in ids]
    net = [float(np.mean([r["network"]["psnr"] for r in by_id[i]])) for i in ids]
    out = {
        "train_renders": size,
        "seeds": len(group),
        "network": {"psnr": float(np.mean(net)), "ci95": bootstrap_ci95(net, groups)},
    }
    for b in BASELINES:
        if all(b in by_id[i][0] for i in ids):
            diff = [net[k] - by_id[i][0][b]["psnr"] for k, i in enumerate(ids)]
            out[f"network_minus_{b}"] = {"psnr": float(np.mean(diff)), "ci95": bootstrap_ci95(diff, groups)}
    return out


def _ci(v: dict | None) -> str:
    if not v or v.get("psnr") is None:
        return "-"
    ci = v.get("ci95")
    return f"{v['psnr']:.2f} [{ci[0]:.2f}, {ci[1]:.2f}]" if ci else f"{v['psnr']:.2f}"


def heading(command: str | None) -> dict:
    """What heads sweep.md: the command that writes it (as the caller spells it), the machine
    and the date."""
    return {
        "command": command,
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs",
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
    }


def markdown(summary: dict) -> str:
    lines = [
        "# Data-size sweep",
        "",
        (f"Written by `{summary['command']}` on " if summary.get("command") else "Written on ")
        + f"{summary['date']}; machine: {summary['machine']}.",
        "",
        "Held-out PSNR (dB, 8-bit sRGB) with 95% intervals (bootstrap over held-out materials); "
        "differences are paired per sample.",
        "",
        "| training renders | seed | epochs | network | mean image | nearest sample | network - mean image | "
        "network - nearest sample | train PSNR (last epoch) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for e in summary["runs"]:
        lines.append(
            f"| {e['train_renders']} | {e['seed']} | {e['epochs']} | {_ci(e['network'])} | {_ci(e.get('mean_image'))} | "
            f"{_ci(e.get('nearest_sample'))} | {_ci(e.get('network_minus_mean_image'))} | "
            f"{_ci(e.get('network_minus_nearest_sample'))} | "
            + ("-" if e.get("train_psnr") is None else f"{e['train_psnr']:.2f}")
            + " |"
        )
    lines += [
        "",
        "Seeds pooled (each held-out sample's PSNR averaged over the seeds):",
        "",
        "| training renders | seeds | network | network - mean image | network - nearest sample |",
        "|---|---|---|---|---|",
    ]
    for p in summary["pooled"]:
        lines.append(
            f"| {p['train_renders']} | {p['seeds']} | {_ci(p['network'])} | {_ci(p.get('network_minus_mean_image'))} | "
            f"{_ci(p.get('network_minus_nearest_sample'))} |"
        )
    pts = [e for e in summary["runs"] if e.get("pt_equal_time")]
    if pts:
        e = pts[-1]
        lines += [
            "",
            f"Path tracing at the network's CPU time ({e['pt_equal_time'].get('spp'):.0f} spp): "
            f"{_ci(e['pt_equal_time'])} dB; denoised (OIDN, its time added): {_ci(e.get('pt_equal_time+oidn'))} dB.",
        ]
    return "\n".join(lines) + "\n"


def data_size_png(summary: dict) -> bytes:
    runs = summary["runs"]
    seeds = sorted({e["seed"] for e in runs}, key=lambda seed: (seed is not None, seed or 0))
    series = []
    for k, seed in enumerate(seeds):
        pts = [
            (e["train_renders"] or 0, e["network"]["psnr"], *(e["network"]["ci95"] or [e["network"]["psnr"]] * 2))
            for e in runs
            if e["seed"] == seed
        ]
        series.append((f"network, seed {seed}", SEED_COLOURS[k % len(SEED_COLOURS)], pts))
    for b, colour, label in (
        ("mean_image", plot.GREY, "--mean image"),
        ("nearest_sample", plot.ORANGE, "--nearest sample"),
    ):
        per_size = {}
        for e in runs:
            if e.get(b):
                per_size.setdefault(e["train_renders"] or 0, e[b]["psnr"])
        if per_size:
            series.append((label, colour, sorted(per_size.items())))
    return plot.png(
        plot.chart(series, "held-out PSNR (dB) against training renders", "training renders (log)", log_x=True)
    )


#: The files a sweep writes into its ``out`` folder (none of them through a link there).
SWEEP_FILES = ("sweep.md", "sweep.json", "data-size.png")


def write_sweep(req: SweepRequest, command: str | None = None) -> tuple[dict, str]:
    """Read ``req.reports`` (report.json files), write sweep.md, sweep.json and data-size.png
    into ``req.out``; returns the summary and the markdown. Nothing is written when a report is
    refused. ``command``: how the caller spells ``req``, sweep.md's heading."""
    out = req.out
    files = [os.path.join(out, name) for name in SWEEP_FILES]
    runfiles.refuse_links(SweepRequest, "out", out, [out], files)
    summary = {**heading(command), **summarise([(p, _load(p)) for p in req.reports])}
    os.makedirs(out, exist_ok=True)
    text = markdown(summary)
    write_bytes_atomic(os.path.join(out, "sweep.md"), text.encode(), inside=out)
    runfiles.write_json(os.path.join(out, "sweep.json"), summary, inside=out)
    write_bytes_atomic(os.path.join(out, "data-size.png"), data_size_png(summary), inside=out)
    return summary, text
