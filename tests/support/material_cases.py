"""Hard-case inputs for checking an implementation of the model (used by the tests).

Directions are in the local frame (n = z) unless a normal is given.
"""

from __future__ import annotations

import itertools

import numpy as np

Z = np.array([0.0, 0.0, 1.0])
#: Roughness values r (alpha = r^2 after clipping r to [0.001, 1]).
HARD_ROUGHNESS = (0.0, 1e-6, 1e-4, 3e-4, 1e-3, 0.01, 1.0)
HARD_COSINES = (1.0, 1e-2, 1e-6, 0.0, -1e-3)


def hard_directions() -> tuple[np.ndarray, np.ndarray]:
    """Pairs (wi, wo) with the hard cosines, mirror, v.h -> 0 and zero-length cases; n = z."""

    def at(cos, phi):
        sin = np.sqrt(max(0.0, 1 - cos * cos))
        return np.array([sin * np.cos(phi), sin * np.sin(phi), cos])

    pairs = []
    for ci, co in itertools.product(HARD_COSINES, HARD_COSINES):
        for dphi in (0.0, np.pi / 2, np.pi, np.pi - 1e-7):
            pairs.append((at(ci, 0.0), at(co, dphi)))
    for c in (1.0, 0.5, 1e-2, 1e-6, 0.0):
        wi = at(c, 0.3)
        pairs.append((wi, np.array([-wi[0], -wi[1], wi[2]])))  # mirror
        pairs.append((wi, -wi + np.array([0, 1e-7, 2e-7])))  # v.h -> 0
    pairs.append((np.zeros(3), Z))
    pairs.append((Z, np.zeros(3)))
    wi, wo = np.array(pairs).transpose(1, 0, 2)
    return wi, wo


#: Shading normals: flat, tangent to the surface, facing away, zero length, not unit length.
HARD_NORMALS = np.array(
    [
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0],  # tangent to the surface
        [0.0, 0.0, -1.0],  # facing away
        [0.6, 0.0, -0.8],
        [0.0, 0.0, 0.0],  # zero length
        [0.3, 0.0, 0.4],  # not normalised
        [3.0, 0.0, 4.0],
    ]
)
