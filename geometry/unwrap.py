"""A UV atlas for a mesh that has none (xatlas), made in a child process.

xatlas 0.0.11 crashes the whole process (SIGSEGV) on some large closed meshes (an
icosphere of 81,920 triangles, measured here; upstream jpcy/xatlas#146 reports the same
kind of crash), and a mesh file is untrusted input. The unwrap therefore runs in a child
Python (``subprocess``, not ``multiprocessing``: dask's worker processes are daemonic and
may not start multiprocessing children); a crash or a timeout becomes an
:class:`UnwrapError` for the caller to report. It runs once per file: the result is cached.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile

import numpy as np

from geometry.atlas import ATLAS_PADDING, ATLAS_RESOLUTION

#: Longest an unwrap may run, seconds (a 200k-triangle mesh takes well under a minute).
UNWRAP_TIMEOUT_S = 900.0


class UnwrapError(RuntimeError):
    """xatlas failed (crashed, timed out or raised) on a mesh."""


def unwrap(positions: np.ndarray, faces: np.ndarray, normals: np.ndarray):
    """An xatlas UV atlas: ``(source, faces, uv)``; new vertex i copies old vertex ``source[i]``.

    Made by :func:`xatlas_unwrap` in a child process; raises UnwrapError if it fails.
    """
    with tempfile.TemporaryDirectory(prefix="shaderball-unwrap-") as folder:
        inputs, outputs = os.path.join(folder, "in.npz"), os.path.join(folder, "out.npz")
        np.savez(inputs, positions=positions, faces=faces, normals=normals)
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([root, os.environ.get("PYTHONPATH", "")]))
        command = [
            sys.executable,
            "-c",
            "import sys, geometry.unwrap as u; u.child_main(sys.argv[1:])",
            inputs,
            outputs,
        ]
        try:
            done = subprocess.run(command, env=env, capture_output=True, timeout=UNWRAP_TIMEOUT_S, check=False)
        except subprocess.TimeoutExpired:
            raise UnwrapError(f"xatlas ran over {UNWRAP_TIMEOUT_S:g} s (UNWRAP_TIMEOUT_S)") from None
        if done.returncode != 0 or not os.path.isfile(outputs):
            tail = done.stderr.decode("utf-8", "replace").strip().splitlines()[-1:] or ["no message"]
            how = f"was killed by signal {-done.returncode}" if done.returncode < 0 else f"exited {done.returncode}"
            raise UnwrapError(f"xatlas failed: its process {how} ({tail[0][:200]})")
        with np.load(outputs, allow_pickle=False) as result:
            return result["source"], result["faces"], result["uv"]


def child_main(argv: list[str]) -> None:
    """The child's entry: read the inputs' npz, unwrap, write the outputs' npz."""
    with np.load(argv[0], allow_pickle=False) as data:
        source, faces, uv = xatlas_unwrap(data["positions"], data["faces"], data["normals"])
    np.savez(argv[1], source=source, faces=faces, uv=uv)


def xatlas_unwrap(positions: np.ndarray, faces: np.ndarray, normals: np.ndarray):
    """xatlas in this process. Chart rotation is off, as in :mod:`geometry.atlas` (xatlas
    "rotates" by swapping u and v, which mirrors a chart and a tangent-space normal map
    with it); texels are square, the longer side of the atlas spans [0, 1]."""
    import xatlas

    atlas = xatlas.Atlas()
    atlas.add_mesh(positions.astype(np.float32), faces.astype(np.uint32), normals.astype(np.float32))
    pack = xatlas.PackOptions()
    pack.padding = ATLAS_PADDING
    pack.resolution = ATLAS_RESOLUTION
    pack.bilinear = True
    pack.rotate_charts = False
    pack.rotate_charts_to_axis = False
    atlas.generate(xatlas.ChartOptions(), pack)
    vmapping, indices, uv01 = atlas[0]
    width, height = int(atlas.width), int(atlas.height)
    side = float(max(width, height))
    uv = uv01.astype(np.float64) * np.array([width / side, height / side])
    return vmapping.astype(np.int64), indices.astype(np.int64), uv
