"""Sun inside ``sunsky`` vs the split (directional sun + sky-only ``sunsky``): noise, bias, time.

``scripts/sun_benchmark.py`` renders the probe scene (pipeline.bench.probe_scene: a ball on
a ground square, seen from the side) and prints two tables (:func:`format_noise`, :func:`format_time`).

Noise: for each light, material and configuration, RMSE at a few spp against a
high-spp reference of the *same* configuration, so it measures noise, not the
configurations' difference. The reference's own noise is removed from the MSE
with two independent half-references (MSE(ref) = MSE(half1, half2) / 4). The
"bias" rows compare the two configurations' references: the split's systematic
difference (sharp penumbra, no visible sun disk).

Time: wall-clock and process CPU seconds (all of Mitsuba's threads) per render
at a larger size, median of ``--repeats``, kernels already compiled. On a shared
machine the CPU time is the steadier measure of work.

About two to three minutes on 2 cores with the defaults. ``--sun-weight-factor``
and ``--sun-weight-exponent`` try other rules for the split's emitter sampling
weights (pipeline.render.emitter.split_sampling_weights).
"""

from __future__ import annotations

import time

import numpy as np

import pipeline.render.emitter as emitter
from pipeline.bench.probe_scene import probe_scene_dict
from sky.lighting import Light

#: name -> (sun mode, fixed (sun, sky) sampling weights or None for the emitter's own)
CONFIGS = {"sunsky": ("sunsky", None), "split": ("split", None)}
LIGHTS = (Light(60.0, 30.0, 2.0), Light(30.0, 60.0, 4.0), Light(10.0, 200.0, 7.0))
MATERIALS = ("diffuse", "glossy", "near_mirror")


def _scene(mi, light, material, config, resolution, configs=CONFIGS):
    sun, weights = configs[config]
    entries, _ = emitter.emitter_dicts(light, sun=sun, variant=mi.variant())
    if weights is not None:
        entries["sun"]["sampling_weight"], entries["sky"]["sampling_weight"] = weights
    return mi.load_dict(
        probe_scene_dict(entries, material=material, resolution=resolution, spp=16, variant=mi.variant())
    )


def _render(mi, scene, spp, seed):
    return np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float64)


def noise_table(
    mi, resolution=64, spp_levels=(16, 150), ref_spp=2048, lights=LIGHTS, materials=MATERIALS, configs=CONFIGS
):
    rows = []
    for light in lights:
        for material in materials:
            refs = {}
            for config in configs:
                scene = _scene(mi, light, material, config, resolution, configs)
                half1 = _render(mi, scene, ref_spp // 2, 10_001)
                half2 = _render(mi, scene, ref_spp // 2, 20_002)
                ref = 0.5 * (half1 + half2)
                ref_mse = np.mean((half1 - half2) ** 2) / 4.0
                refs[config] = ref
                for spp in spp_levels:
                    raw_mse = float(np.mean((_render(mi, scene, spp, 1) - ref) ** 2))
                    rows.append(
                        {
                            "light": light,
                            "material": material,
                            "config": config,
                            "spp": spp,
                            "rmse": float(np.sqrt(max(raw_mse - ref_mse, 0.0))),
                            "raw_rmse": float(np.sqrt(raw_mse)),
                            "ref_rmse": float(np.sqrt(ref_mse)),
                            "mean": float(ref.mean()),
                        }
                    )
            names = list(configs)
            for other in names[1:]:
                bias = float(np.sqrt(np.mean((refs[names[0]] - refs[other]) ** 2)))
                rows.append(
                    {
                        "light": light,
                        "material": material,
                        "config": f"bias: {other} vs {names[0]}",
                        "raw_rmse": bias,
                        "mean": float(refs[names[0]].mean()),
                    }
                )
    return rows


def time_table(mi, resolution=256, spp=64, repeats=3, light=LIGHTS[1], materials=MATERIALS, configs=CONFIGS):
    rows = []
    for material in materials:
        for config in configs:
            scene = _scene(mi, light, material, config, resolution, configs)
            _render(mi, scene, 4, 0)  # compile outside the timings
            wall, cpu = [], []
            for r in range(repeats):
                start, start_cpu = time.perf_counter(), time.process_time()
                _render(mi, scene, spp, 100 + r)
                wall.append(time.perf_counter() - start)
                cpu.append(time.process_time() - start_cpu)
            rows.append((material, config, float(np.median(wall)), float(np.median(cpu))))
    return rows


def _light(light: Light) -> str:
    return f"({light.elevation_deg:g}, {light.azimuth_deg:g}, {light.turbidity:g})"


def format_noise(rows) -> str:
    lines = [
        "| light (el, az, T) | material | config | spp | RMSE | RMSE / mean | raw RMSE | ref. noise |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        head = f"| {_light(r['light'])} | {r['material']} | {r['config']} |"
        if "spp" not in r:
            lines.append(f"{head} | | | {r['raw_rmse']:.5f} | |")
            continue
        lines.append(
            f"{head} {r['spp']} | {r['rmse']:.5f} | {r['rmse'] / r['mean']:.3f} | "
            f"{r['raw_rmse']:.5f} | {r['ref_rmse']:.5f} |"
        )
    return "\n".join(lines)


def format_time(rows, resolution, spp) -> str:
    lines = [
        f"| material | config | wall s per {resolution}x{resolution} render at {spp} spp | CPU s (all threads) |",
        "|---|---|---|---|",
    ]
    for material, config, wall, cpu in rows:
        lines.append(f"| {material} | {config} | {wall:.3f} | {cpu:.3f} |")
    return "\n".join(lines)
