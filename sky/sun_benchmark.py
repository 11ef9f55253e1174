"""Sun inside ``sunsky`` vs the split (directional sun + sky-only ``sunsky``): noise and time.

``python -m sky.sun_benchmark`` renders the probe scene (sky.probe_scene: a ball on
a ground square, seen from the side) for each light, material and emitter
configuration at a few spp, and prints RMSE against a high-spp reference of the
*same* configuration (so it measures noise, not the configurations' difference),
and the render time with kernels already compiled. The reference's own noise is
removed from the MSE using two independent half-references. The last column
block compares the two references with each other: the split's bias (penumbra,
no visible disk). Takes about two minutes on 2 cores with the defaults.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from sky.emitter import emitter_dicts
from sky.lighting import Light
from sky.probe_scene import probe_scene_dict

CONFIGS = {
    # name: (sun mode, (sun, sky) sampling weights or None for the emitter's own)
    "sunsky": ("sunsky", None),
    "split 1:1": ("split", (1.0, 1.0)),
    "split 3:1": ("split", (3.0, 1.0)),
}
LIGHTS = (Light(35.0, 60.0, 3.0), Light(10.0, 200.0, 7.0))
MATERIALS = ("diffuse", "glossy", "near_mirror")


def _scene(mi, light, material, config, resolution, configs=CONFIGS):
    sun, weights = configs[config]
    entries, _ = emitter_dicts(light, sun=sun)
    if weights is not None:
        entries["sun"]["sampling_weight"], entries["sky"]["sampling_weight"] = weights
    return mi.load_dict(probe_scene_dict(entries, material=material, resolution=resolution, spp=16))


def _render(mi, scene, spp, seed):
    image = mi.render(scene, spp=spp, seed=seed)
    return np.array(image, dtype=np.float64)


def _timed(mi, scene, spp, seed, repeats):
    times = []
    for r in range(repeats):
        start = time.perf_counter()
        image = _render(mi, scene, spp, seed + r)
        times.append(time.perf_counter() - start)
    return image, float(np.median(times))


def run(
    resolution=64,
    spp_levels=(16, 64, 150),
    ref_spp=2048,
    repeats=3,
    lights=LIGHTS,
    materials=MATERIALS,
    configs=CONFIGS,
):
    from pipeline.mitsuba_env import load_mitsuba

    mi = load_mitsuba("llvm_ad_rgb")
    rows = []
    for light in lights:
        for material in materials:
            refs = {}
            for config in configs:
                scene = _scene(mi, light, material, config, resolution, configs)
                _render(mi, scene, 4, 0)  # compile outside the timings
                half1 = _render(mi, scene, ref_spp // 2, 10_001)
                half2 = _render(mi, scene, ref_spp // 2, 20_002)
                ref = 0.5 * (half1 + half2)
                ref_mse = np.mean((half1 - half2) ** 2) / 4.0
                refs[config] = ref
                for spp in spp_levels:
                    image, seconds = _timed(mi, scene, spp, 1, repeats)
                    mse = max(np.mean((image - ref) ** 2) - ref_mse, 0.0)
                    rows.append(
                        {
                            "light": light.to_dict(),
                            "material": material,
                            "config": config,
                            "spp": spp,
                            "rmse": float(np.sqrt(mse)),
                            "rel_rmse": float(np.sqrt(mse) / max(ref.mean(), 1e-12)),
                            "seconds": seconds,
                            "ref_mean": float(ref.mean()),
                        }
                    )
            for config in configs:
                if configs[config][0] == "split" and "sunsky" in refs:
                    bias = float(np.sqrt(np.mean((refs["sunsky"] - refs[config]) ** 2)))
                    rows.append({"light": light.to_dict(), "material": material, "config": f"bias {config} vs sunsky", "rmse": bias})
                    break
    return rows


def format_table(rows) -> str:
    lines = ["| light (el, az, T) | material | config | spp | RMSE | rel. RMSE | time s |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        light = r["light"]
        name = f"({light['elevation_deg']:g}, {light['azimuth_deg']:g}, {light['turbidity']:g})"
        if "spp" not in r:
            lines.append(f"| {name} | {r['material']} | {r['config']} (ref vs ref) | | {r['rmse']:.5f} | | |")
            continue
        lines.append(
            f"| {name} | {r['material']} | {r['config']} | {r['spp']} | {r['rmse']:.5f} | "
            f"{r['rel_rmse']:.3f} | {r['seconds']:.3f} |"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--ref-spp", type=int, default=2048)
    parser.add_argument("--spp", type=int, nargs="+", default=[16, 64, 150])
    parser.add_argument("--repeats", type=int, default=3, help="timed renders per point (median)")
    args = parser.parse_args(argv)
    rows = run(args.resolution, tuple(args.spp), args.ref_spp, args.repeats)
    print(format_table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
