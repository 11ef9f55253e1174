"""Intel Open Image Denoise (``pyoidn``): the one call of its RT filter, in HDR mode.

The guide buffers it may be given are made where the geometry is known:
:mod:`pipeline.neural.denoise` (``AuxBuffers``, supersampled, for `shaderball evaluate`) and
:mod:`pipeline.study.denoise` (from the study's screen-space maps). Both are noise-free, so
``clean_aux`` is on whenever a guide is given.
"""

from __future__ import annotations

import time

import numpy as np


def denoise(
    image: np.ndarray, albedo: np.ndarray | None = None, normal: np.ndarray | None = None
) -> tuple[np.ndarray, float, float]:
    """(denoised HDR image, wall seconds, CPU seconds) of OIDN on ``image`` (NaN as 0, negatives
    clipped to 0): colour alone, with the albedo, or with the albedo and the normal."""
    import pyoidn

    colour = np.ascontiguousarray(np.maximum(np.nan_to_num(image), 0.0), dtype=np.float32)
    kwargs = {}
    if albedo is not None:
        kwargs["albedo"] = np.ascontiguousarray(albedo, dtype=np.float32)
        if normal is not None:
            kwargs["normal"] = np.ascontiguousarray(normal, dtype=np.float32)
        kwargs["clean_aux"] = True
    wall, cpu = time.perf_counter(), time.process_time()
    out = pyoidn.denoise(colour, hdr=True, **kwargs)
    return np.asarray(out, dtype=np.float32), time.perf_counter() - wall, time.process_time() - cpu
