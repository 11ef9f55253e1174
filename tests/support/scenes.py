"""What the scene tests share: a small spec's text (32 px, 4 spp), the CLI, a mesh file and
a small sunny environment map written by the test (nothing is downloaded)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from click.testing import CliRunner

#: Every small scene build's [materials] and [render]: fast real renders.
SMALL = """
[materials]
texture_resolution = 32

[render]
resolution = 32
spp = 4
"""
#: The geometry layers stored beside the maps.
GEOMETRY_LAYERS = (
    '[storage]\nlayers = ["diffuse", "specular", "roughness", "normal", "mask", "geometry_normal", "depth"]\n'
)


def small_spec(name: str, seed: int = 11, materials: int = 4, lights: int = 2, shard_size: int = 2) -> str:
    """A spec's [dataset], [materials] and [render] (the scene and lighting are the caller's)."""
    return (
        f'\n[dataset]\nname = "{name}"\nseed = {seed}\nmaterials = {materials}\n'
        f"lights_per_material = {lights}\nsvbrdf_fraction = 0.5\nshard_size = {shard_size}\n" + SMALL
    )


def cli(*args):
    """``shaderball ARGS`` in this process (click's runner); the result has exit_code, output."""
    from cli import main

    return CliRunner().invoke(main, [str(a) for a in args])


def records(root: Path) -> list[dict]:
    """Every record file of a dataset folder, in sample order."""
    return [json.loads(p.read_text()) for p in sorted((root / "shards").rglob("m*.json"))]


def mesh_file(folder: Path, name: str = "wedge.obj") -> Path:
    """A small closed mesh (a cone) written by trimesh."""
    import trimesh

    path = folder / name
    trimesh.creation.cone(radius=0.4, height=1.0, sections=24).export(path)
    return path


def environment_map(path: Path, sun_row: int = 6, sun_col: int = 40) -> Path:
    """A small sunny lat-long map (32 x 64): a blue-to-white gradient and a bright 2x2 'sun'."""
    from pipeline.store.exr import write_exr

    h, w = 32, 64
    v = (np.arange(h, dtype=np.float32)[:, None, None] + 0.5) / h
    sky = np.broadcast_to(np.array([0.3, 0.5, 1.0], np.float32) * (1.2 - v), (h, w, 3)).copy()
    sky[sun_row : sun_row + 2, sun_col : sun_col + 2] = 500.0
    write_exr(str(path), {"render": sky})
    return path
