"""The sRGB transfer function (IEC 61966-2-1): the one definition in ``pipeline``.

``materials.colorspace`` decodes imported 8-bit maps with colour-science's implementation:
a domain package may not import ``pipeline``, and its decoded values are bytes of every
dataset, so it keeps its own (decode only; nothing in ``materials`` encodes).
"""

from __future__ import annotations

import numpy as np


def srgb_encode(linear01: np.ndarray) -> np.ndarray:
    """Linear [0, 1] -> sRGB transfer curve (IEC 61966-2-1); input clamped to [0, 1]."""
    x = np.clip(linear01, 0.0, 1.0)
    return np.where(x <= 0.0031308, x * 12.92, np.power(x, 1 / 2.4) * 1.055 - 0.055)


def srgb_decode(encoded01: np.ndarray) -> np.ndarray:
    """Inverse of :func:`srgb_encode` on [0, 1]."""
    y = np.clip(encoded01, 0.0, 1.0)
    return np.where(y <= 0.04045, y / 12.92, np.power((y + 0.055) / 1.055, 2.4))
