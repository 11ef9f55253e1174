"""What another CPU changes in a dataset, measured on this one (docs/build.md).

A user's laptop, CI and a cluster's nodes have other CPUs: AVX2 without AVX-512 (an AMD
EPYC), AVX-512 (the machine here), aarch64. Two things in a build
depend on the CPU: numpy's SIMD kernels (the last bits of its transcendental functions, used
by the material samplers and map generators) and drjit's LLVM JIT, which compiles every
kernel for the host (``rocketlake`` with 16 lanes here, ``znver3`` with 8 on that EPYC).

This builds one spec four times on this machine, each in a fresh process with a fresh
kernel cache and geometry cache: natively; with numpy's AVX-512 kernels switched off
(``NPY_DISABLE_CPU_FEATURES``); with drjit's JIT targeting an AVX2 CPU with 8 lanes
(``jit_llvm_set_target``, a drjit-core function read through ctypes); and with both, which is
what an AVX2 machine runs. It compares each with the native build: plan digests, files
byte for byte, and where a render differs, the size of the difference against the render's
own noise (``stats.noise_rmse``, the RMSE of the render against its expectation: two
independent renders differ by about 1.41 times it).

    .venv/bin/python scripts/cross_cpu.py manifests/smoke.toml --out /tmp/cross-cpu

writes ``report.md`` and ``report.json`` there (about a minute for the smoke spec,
:func:`cross_cpu_report`). Each build runs in a child process: ``scripts/cross_cpu.py --child``
(:func:`child`).
"""

from __future__ import annotations

import ctypes
import datetime
import json
import math
import os
import platform
import subprocess
import sys
import time

import numpy as np

from pipeline.errors import ShaderballError
from pipeline.fields import FieldError
from pipeline.fields.rules import format_value
from pipeline.render.mitsuba_env import (
    LLVM_VARIANT,
    llvm_target,
    load_mitsuba,
    machine_fingerprint,
    numpy_dispatch_targets,
)
from pipeline.run.build import build
from pipeline.run.cluster.options import ClusterOptions
from pipeline.store.atomic import write_text_atomic
from pipeline.store.exr import read_exr
from pipeline.store.layout import Layout

#: name -> (numpy's AVX-512 kernels off, drjit's JIT for AVX2 with 8 lanes)
EMULATIONS = {
    "native": (False, False),
    "numpy-avx2": (True, False),
    "llvm-avx2": (False, True),
    "avx2": (True, True),
}
AVX2_CPU = "znver3"  # an AMD EPYC (AVX2, FMA, no AVX-512)
AVX2_WIDTH = 8
#: The script whose ``--child`` mode runs one build (:func:`child`) in a fresh process.
CHILD_SCRIPT = os.path.join(
    os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "scripts", "cross_cpu.py"
)
#: How a user re-runs the measurement (the report's header).
COMMAND = ".venv/bin/python scripts/cross_cpu.py {spec} --out DIR"


def emulations() -> dict[str, tuple[bool, bool]]:
    """The emulations this machine can run: retargeting the JIT to an AVX2 CPU needs x86-64
    (elsewhere the numpy one only, which switches off whatever SIMD kernels numpy has)."""
    if platform.machine() in ("x86_64", "AMD64"):
        return dict(EMULATIONS)
    return {"native": (False, False), "numpy-avx2": (True, False)}


def numpy_without_avx512() -> str:
    """The value of NPY_DISABLE_CPU_FEATURES that leaves numpy its AVX2 kernels at most (on a
    machine of another architecture: every dispatched kernel off, its baseline only)."""
    targets = numpy_dispatch_targets()
    if platform.machine() not in ("x86_64", "AMD64"):
        return " ".join(targets)
    return " ".join(name for name in targets if name.startswith(("AVX512", "X86_V4")))


def set_llvm_avx2_target() -> tuple[str, int]:
    """Make drjit's LLVM JIT compile for an AVX2 CPU with 8 lanes; return (cpu, width) now.

    Must run after Mitsuba has loaded the llvm backend and before any kernel is compiled."""
    import drjit as dr

    lib = ctypes.CDLL(os.path.join(os.path.dirname(dr.__file__), "libdrjit-core.so"))
    features = lib._Z24jit_llvm_target_featuresv
    features.restype = ctypes.c_char_p
    host = features().decode()
    avx2 = ",".join(
        "-" + f[1:] if f.startswith("+") and f[1:].startswith(("avx512", "avx10", "amx", "evex512")) else f
        for f in host.split(",")
    )
    lib._Z19jit_llvm_set_targetPKcS0_j.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32]
    lib._Z19jit_llvm_set_targetPKcS0_j(AVX2_CPU.encode(), avx2.encode(), AVX2_WIDTH)
    return llvm_target()


def child(spec: str, out: str, llvm_avx2: bool) -> None:
    """One build in this process (``--workers 0``), the JIT retargeted first if asked."""
    load_mitsuba(LLVM_VARIANT)
    if llvm_avx2:
        set_llvm_avx2_target()
    build(spec, out, cluster=ClusterOptions(workers=0))


def run_emulation(spec: str, out: str, name: str) -> float:
    numpy_avx2, llvm_avx2 = emulations()[name]
    # fresh caches: drjit's kernels, and the shaderball's mesh, UV atlas and G-buffer, all
    # made again under the emulated CPU rather than read from this machine's cache
    env = dict(
        os.environ,
        DRJIT_CACHE_DIR=os.path.join(out, f".drjit-cache-{name}"),
        SHADERBALL_CACHE=os.path.join(out, f".shaderball-cache-{name}"),
    )
    if numpy_avx2:
        env["NPY_DISABLE_CPU_FEATURES"] = numpy_without_avx512()
    else:
        env.pop("NPY_DISABLE_CPU_FEATURES", None)
    command = [sys.executable, CHILD_SCRIPT, "--child", spec, os.path.join(out, name)]
    if llvm_avx2:
        command.append("--llvm-avx2")
    start = time.perf_counter()
    run = subprocess.run(command, env=env, capture_output=True, text=True)
    if run.returncode != 0:
        raise ShaderballError(f"the {name} build failed (exit {run.returncode}): {run.stderr.strip()[-2000:]}")
    return time.perf_counter() - start


def _records(root: str) -> dict[str, dict]:
    with open(Layout(root).manifest, encoding="utf-8") as f:
        return {r["id"]: r for r in map(json.loads, f)}


def compare(native: str, other: str) -> dict:
    """How ``other`` differs from ``native``: digests, files, and renders against their noise."""
    a, b = _records(native), _records(other)
    desc = [json.load(open(Layout(root).description, encoding="utf-8")) for root in (native, other)]
    files = {}
    ratios = []
    map_pixels: list[int] = []
    map_max: dict[str, float] = {}
    for sample_id, ra in a.items():
        rb = b[sample_id]
        hashes_b = {f["path"]: f["sha256"] for f in rb["files"]}
        for f in ra["files"]:
            role = f["role"]
            same = hashes_b.get(f["path"]) == f["sha256"]
            counts = files.setdefault(role, {"files": 0, "identical": 0})
            if f["path"] in counts.get("_seen", set()):
                continue
            counts.setdefault("_seen", set()).add(f["path"])
            counts["files"] += 1
            counts["identical"] += same
            if role == "maps" and not same:
                layers_a = read_exr(os.path.join(native, f["path"])).layers
                layers_b = read_exr(os.path.join(other, f["path"])).layers
                differ = np.zeros(next(iter(layers_a.values())).shape[:2], dtype=bool)
                for layer, pixels in layers_a.items():
                    delta = np.abs(pixels.astype(np.float64) - layers_b[layer].astype(np.float64))
                    differ |= np.any(delta > 0, axis=-1)
                    map_max[layer] = max(map_max.get(layer, 0.0), float(delta.max()))
                map_pixels.append(int(differ.sum()))
            if role == "render" and not same:
                image_a = read_exr(os.path.join(native, f["path"])).layers["render"]
                image_b = read_exr(os.path.join(other, f["path"])).layers["render"]
                rmse = float(np.sqrt(np.mean((image_a.astype(np.float64) - image_b) ** 2)))
                noise = float(ra["stats"]["noise_rmse"])
                differing = float(np.mean(np.any(image_a != image_b, axis=-1)))
                ratios.append((rmse / noise if noise > 0 else math.inf, differing))
    for counts in files.values():
        counts.pop("_seen", None)
    out = {
        "plan_digest_equal": desc[0]["plan_digest"] == desc[1]["plan_digest"],
        "files": files,
        "renders_differing": len(ratios),
    }
    if map_pixels:
        out["maps_differing"] = {"pixels_per_file": map_pixels, "max_abs_difference": map_max}
    if ratios:
        rmse_over_noise = [r for r, _ in ratios]
        out["rmse_over_noise"] = {
            "median": float(np.median(rmse_over_noise)),
            "max": float(np.max(rmse_over_noise)),
        }
        out["pixels_differing"] = {
            "median": float(np.median([d for _, d in ratios])),
            "max": float(np.max([d for _, d in ratios])),
        }
    return out


def report_markdown(result: dict) -> str:
    lines = [
        "# What another CPU changes: builds of one spec under emulated CPUs",
        "",
        f"Written by `{result['command']}` on {result['date']}.",
        "",
        f"Spec `{result['spec']}` on {result['host']['cpu_model']} (LLVM target "
        f"{result['host']['llvm_target_cpu']}, {result['host']['llvm_vector_width']} lanes; numpy SIMD "
        f"{', '.join(result['host']['numpy_simd'])}). Re-run: `{result['command']}`.",
        "",
        "| build | plan digest | maps identical | textures identical | renders identical | "
        "render RMSE of the difference / render noise (median, max) | pixels differing (median, max) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, row in result["builds"].items():
        if name == "native":
            continue
        files = row["files"]

        def frac(role, files=files):
            c = files.get(role, {"files": 0, "identical": 0})
            return f"{c['identical']}/{c['files']}"

        ratio = row.get("rmse_over_noise")
        pixels = row.get("pixels_differing")
        lines.append(
            f"| {name} | {'same' if row['plan_digest_equal'] else 'DIFFERENT'} | {frac('maps')} | "
            f"{frac('texture')} | {frac('render')} | "
            + (f"{ratio['median']:.3g}, {ratio['max']:.3g}" if ratio else "-")
            + " | "
            + (f"{pixels['median']:.3g}, {pixels['max']:.3g}" if pixels else "-")
            + " |"
        )
    for name, row in result["builds"].items():
        maps = row.get("maps_differing")
        if maps:
            worst = ", ".join(f"{layer} {value:.3g}" for layer, value in sorted(maps["max_abs_difference"].items()))
            lines.append(
                f"\n{name}: the maps that differ differ in {', '.join(map(str, maps['pixels_per_file']))} "
                f"pixel(s) each; largest difference per layer: {worst}."
            )
    lines += [
        "",
        "Two independent renders of a sample differ by an RMSE of about 1.41 times its noise "
        "(`stats.noise_rmse`); a ratio far below that is a difference within the noise.",
        "",
    ]
    return "\n".join(lines)


def cross_cpu_report(spec: str, out: str) -> dict:
    """Build ``spec`` under every emulation into the new folder ``out``, compare each with the
    native build, write report.json and report.md there; returns the report."""
    if os.path.exists(out):
        raise FieldError("out", out, "a folder that does not exist yet", what=f"{format_value(out)} exists", name="out")
    os.makedirs(out)
    load_mitsuba(LLVM_VARIANT)
    seconds = {name: run_emulation(spec, out, name) for name in emulations()}
    native = os.path.join(out, "native")
    result = {
        "spec": spec,
        "command": COMMAND.format(spec=spec),
        "host": machine_fingerprint(),
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "avx2_target": {"cpu": AVX2_CPU, "vector_width": AVX2_WIDTH, "numpy_disabled": numpy_without_avx512()},
        "builds": {
            name: {"seconds": round(seconds[name], 1), **compare(native, os.path.join(out, name))} for name in seconds
        },
    }
    write_text_atomic(os.path.join(out, "report.json"), json.dumps(result, indent=1))
    write_text_atomic(os.path.join(out, "report.md"), report_markdown(result))
    return result
