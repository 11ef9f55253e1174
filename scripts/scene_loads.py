"""What a worker pays to load a large mesh and a large environment map, and what it pays again:
a measurement, printed, not a timed test.

    .venv/bin/python scripts/scene_loads.py [--faces 200000] [--map-height 2048]

A grid mesh of about ``--faces`` faces with its own UVs (an OBJ) and a lat-long EXR of
``2 * --map-height`` x ``--map-height`` are written to a temporary folder. The mesh is built
once (the gate, the canonical mesh, the geometry cache: what a build's driver does), then
loaded from the cache in a fresh process (what each worker does, once); the map is read,
hashed and decoded once, then asked for again (every later lighting of a worker), and made
into Mitsuba's envmap emitter (its sampling tables).
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def grid_obj(path: Path, faces: int) -> int:
    """A wavy square grid of about ``faces`` triangles with per-vertex UVs; returns its faces."""
    import numpy as np

    n = max(2, int(math.sqrt(faces / 2)) + 1)
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    z = 0.1 * np.sin(6 * u) * np.cos(6 * v)
    lines = [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in zip(u.ravel(), v.ravel(), z.ravel())]
    lines += [f"vt {a:.6f} {b:.6f}" for a, b in zip(u.ravel(), v.ravel())]
    i = np.arange(n * n).reshape(n, n)[:-1, :-1].ravel() + 1
    quads = np.stack([i, i + 1, i + n + 1, i + n], axis=1)
    for a, b, c, d in quads.tolist():
        lines.append(f"f {a}/{a} {b}/{b} {c}/{c}")
        lines.append(f"f {a}/{a} {c}/{c} {d}/{d}")
    path.write_text("\n".join(lines) + "\n")
    return 2 * len(quads)


WARM_LOAD = """
import sys, time
sys.path.insert(0, {repo!r})
from geometry.objects import build_object
start = time.perf_counter()
build_object({path!r})
print(time.perf_counter() - start)
"""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="scripts/scene_loads.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--faces", type=int, default=200_000, help="faces of the grid mesh (1000 to 2000000)")
    parser.add_argument("--map-height", type=int, default=2048, help="map height in pixels (16 to 4096)")
    args = parser.parse_args(argv)
    if not 1000 <= args.faces <= 2_000_000:
        parser.error(f"--faces {args.faces}: 1000 to 2000000 faces")
    if not 16 <= args.map_height <= 4096:
        parser.error(f"--map-height {args.map_height}: 16 to 4096 pixels")

    import numpy as np

    with tempfile.TemporaryDirectory(prefix="shaderball-scene-loads-") as tmp:
        os.environ["SHADERBALL_CACHE"] = os.path.join(tmp, "cache")
        from geometry.objects import build_object
        from pipeline.render.envmap import environment_emitter_dict, load_environment
        from pipeline.render.mitsuba_env import load_mitsuba
        from pipeline.store.exr import write_exr

        mesh = Path(tmp) / "grid.obj"
        faces = grid_obj(mesh, args.faces)
        start = time.perf_counter()
        obj = build_object(str(mesh))
        cold = time.perf_counter() - start
        warm = float(
            subprocess.run(
                [sys.executable, "-c", WARM_LOAD.format(repo=str(REPO), path=str(mesh))],
                check=True,
                capture_output=True,
                text=True,
                env=dict(os.environ),
            ).stdout.split()[-1]
        )
        h = args.map_height
        rng = np.random.default_rng(0)
        radiance = rng.random((h, 2 * h, 3), dtype=np.float32)
        radiance[h // 4 : h // 4 + 8, h // 2 : h // 2 + 8] = 5000.0
        path = Path(tmp) / "map.exr"
        write_exr(str(path), {"render": radiance})
        start = time.perf_counter()
        loaded = load_environment(path)
        first_map = time.perf_counter() - start
        start = time.perf_counter()
        load_environment(path)
        again_map = time.perf_counter() - start
        mi = load_mitsuba("llvm_ad_rgb")
        start = time.perf_counter()
        emitter = mi.load_dict(environment_emitter_dict(loaded.radiance, 30.0, 1.0, variant="llvm_ad_rgb"))
        tables = time.perf_counter() - start
        del emitter
        print(f"mesh: {faces} faces, {len(obj.material_mesh.vertices)} vertices, UVs from the {obj.uv_source}")
        print(f"  built once (gate, canonical mesh, geometry cache): {cold:.2f} s")
        print(f"  loaded by a fresh worker from the cache (gate + PLY): {warm:.2f} s")
        print(f"map: {2 * h} x {h} EXR, {path.stat().st_size / 1e6:.1f} MB")
        print(f"  first lighting (read, SHA-256, decode, checks): {first_map:.2f} s")
        print(f"  every later lighting of the worker: {again_map * 1000:.2f} ms")
        print(f"  envmap emitter loaded (bitmap + sampling tables): {tables:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
