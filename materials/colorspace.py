"""Colour helpers (sRGB decoding via colour-science, HSV), imported lazily.

colour-science warns at import when matplotlib is missing; that warning is
irrelevant here and is silenced.
"""

from __future__ import annotations

import functools
import warnings

import numpy as np

#: Colour spaces a map may be read in: "raw" takes stored values as linear
#: (Deschaintre et al.'s code), "srgb" decodes the sRGB transfer function.
COLORSPACES = ("raw", "srgb")


@functools.lru_cache(maxsize=1)
def _colour():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import colour

    return colour


def srgb_decode(values) -> np.ndarray:
    """sRGB-encoded values in [0, 1] to linear (IEC 61966-2-1 EOTF), float64."""
    return np.asarray(_colour().cctf_decoding(np.asarray(values, dtype=np.float64), function="sRGB"))


def hsv_to_rgb(hsv) -> np.ndarray:
    """HSV (..., 3), all in [0, 1], to RGB in the same encoding as V."""
    return np.asarray(_colour().HSV_to_RGB(np.asarray(hsv, dtype=np.float64)))
