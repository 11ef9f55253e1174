"""The scores of an evaluation: an image's PSNR and SSIM on 8-bit sRGB and relMSE and
HDR-FLIP on linear HDR against its reference (a network output's HDR is the inverse tone map
of it capped at :data:`NETWORK_Y_CAP`), each method's means with 95% intervals by material,
and the Table 1-shaped markdown table of them."""

from __future__ import annotations

import numpy as np

from pipeline.image import metrics
from pipeline.image.tonemap import inverse_tonemap, to_srgb8
from pipeline.neural.report import bootstrap_ci95

#: The network's (and the mean image's) output is capped here before the inverse tone map
#: for relMSE and HDR-FLIP: the largest value that does not round to 8-bit 255. An output
#: of 1 says only "at least this bright"; uncapped it inverts to 1e6 / exposure.
NETWORK_Y_CAP = 254.5 / 255.0


def image_scores(
    hdr: np.ndarray, srgb8: np.ndarray, ref_hdr: np.ndarray, ref8: np.ndarray, time_s: float, flip: bool = True, **extra
) -> dict:
    return {
        "psnr": metrics.psnr8(srgb8, ref8),
        "ssim": metrics.ssim8(srgb8, ref8),
        "relmse": metrics.relmse(hdr, ref_hdr),
        "flip": metrics.hdr_flip(hdr, ref_hdr) if flip else None,
        "time_s": time_s,
        **extra,
    }


def network_hdr(y: np.ndarray, exposure: float) -> np.ndarray:
    """A [0, 1] output as linear radiance for relMSE and HDR-FLIP, capped at NETWORK_Y_CAP."""
    return inverse_tonemap(np.minimum(y, NETWORK_Y_CAP), exposure)


def ldr_scores(y: np.ndarray, ref_hdr, ref8, exposure: float, time_s: float, flip: bool = True, **extra) -> dict:
    """Scores of a [0, 1] image (the network's, the mean image), with its saturated fraction."""
    y8 = to_srgb8(y)
    saturated = float(np.count_nonzero((y8 == 0) | (y8 == 255)) / y8.size)
    return image_scores(network_hdr(y, exposure), y8, ref_hdr, ref8, time_s, flip, saturated=saturated, **extra)


def method_means(rows: list[dict]) -> dict:
    """Each method's mean scores over the samples that have it, with 95% intervals by
    material (:func:`pipeline.neural.report.bootstrap_ci95`)."""
    methods = [k for k in rows[0] if k not in ("id", "material_id", "class")]
    means = {
        m: {k: _mean([r[m][k] for r in rows if m in r]) for k, v in rows[0][m].items() if not isinstance(v, str)}
        for m in methods
    }
    for m in methods:
        have = [r for r in rows if m in r]
        groups = [r["material_id"] for r in have]
        means[m]["ci95"] = {
            k: bootstrap_ci95([r[m][k] for r in have], groups) for k in ("psnr", "ssim", "relmse", "flip")
        }
    return means


def _mean(values):
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


def method_label(method: str, means: dict | None = None) -> str:
    if method == "network":
        return "neural renderer"
    if method == "mean_image":
        return "mean training image"
    if method == "nearest_sample":
        return "nearest training sample (same class, lighting)"
    if method.startswith("pt_equal_time"):
        spp = (means or {}).get("pt_equal_time", {}).get("spp")
        label = f"path tracing, equal CPU time ({spp:.0f} spp)" if spp else "path tracing, equal CPU time"
        return label + (" + OIDN (its time added)" if method.endswith("+oidn") else "")
    spp, _, extra = method[2:].partition("+")
    return f"path tracing, {spp} spp" + {"": "", "oidn": " + OIDN", "oidn-colour": " + OIDN, colour only"}[extra]


def markdown_table(
    means: dict, samples: int, resolution: int, reference_spp: int | None = None, equal_time: dict | None = None
) -> str:
    """Table 1: a row per method; the network's and the equal-time row's matched CPU times in a
    column of their own (``equal_time``: :func:`measure_equal_time`'s figures)."""

    def fmt(v, spec):
        return "-" if v is None else format(v, spec)

    def interval(m, key, spec):
        ci = (m.get("ci95") or {}).get(key)
        return f"{fmt(m[key], spec)} [{fmt(ci[0], spec)}, {fmt(ci[1], spec)}]" if ci else fmt(m[key], spec)

    lines = [
        f"{samples} samples at {resolution}x{resolution}"
        + (f", references of {reference_spp} spp" if reference_spp else "")
        + "; PSNR/SSIM on 8-bit sRGB, relMSE and HDR-FLIP on linear HDR; time per image; "
        "[95% interval, bootstrap over materials]",
        "",
        "| method | PSNR (dB) | SSIM | relMSE | HDR-FLIP | time (ms) | CPU time matched (ms) |",
        "|---|---|---|---|---|---|---|",
    ]
    matched = {}
    if equal_time:
        matched = {"network": equal_time["network_cpu_s"], "pt_equal_time": equal_time.get("pt_cpu_s_at_spp")}
    for method, m in means.items():
        cpu = matched.get(method)
        lines.append(
            f"| {method_label(method, means)} | {interval(m, 'psnr', '.2f')} | {fmt(m['ssim'], '.4f')} | "
            f"{fmt(m['relmse'], '.4g')} | {fmt(m['flip'], '.4f')} | {fmt(m['time_s'] * 1000, '.1f')} | "
            f"{fmt(None if cpu is None else cpu * 1000, '.1f')} |"
        )
    if equal_time:
        lines += [
            "",
            f"Equal time: the network's CPU time per image on one torch thread, "
            f"{1000 * equal_time['network_cpu_s']:.1f} ms, matched by path tracing at {equal_time['spp']} spp "
            f"({1000 * equal_time['pt_cpu_s_at_spp']:.1f} ms of CPU on the line through its CPU times at "
            + " and ".join(f"{k} spp ({1000 * v:.1f} ms)" for k, v in equal_time["pt_cpu_s"].items())
            + "); time (ms) is wall time per image.",
        ]
    return "\n".join(lines) + "\n"
