"""Evaluating Mitsuba's ``sunsky`` emitter directly, outside any render.

One :class:`SunskyProbe` per process holds three loaded ``sunsky`` emitters
(sun and sky, sun only, sky only) and moves them to a new light through
``mi.traverse`` (no kernel recompilation: direction and turbidity are opaque
JIT values). It answers the questions the emitter description and the hard-case
policy need: the sun disk's radiance (uniform over the disk in Mitsuba 3.9's
default, non-``complex_sun`` RGB model), its irradiance, the sky's total
radiant power per unit area, and the smallest radiance component anywhere on
the upper hemisphere.
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np

from pipeline.render.mitsuba_env import load_mitsuba
from sky.directions import sun_direction
from sky.emitter import SUN_SOLID_ANGLE_SR, hemisphere_check_directions, sunsky_dict


class SunskyProbe:
    """Three ``sunsky`` emitters kept in step with one light; see the module doc."""

    def __init__(self, variant: str):
        self.mi = load_mitsuba(variant)
        start = sun_direction(45.0, 0.0)
        self._emitters = {
            "both": self.mi.load_dict(sunsky_dict(start, 3.0)),
            "sun": self.mi.load_dict(sunsky_dict(start, 3.0, sky_scale=0.0)),
            "sky": self.mi.load_dict(sunsky_dict(start, 3.0, sun_scale=0.0)),
        }
        self._params = {k: self.mi.traverse(e) for k, e in self._emitters.items()}
        self.direction = start
        self.turbidity = 3.0

    def set(self, direction, turbidity: float, parts=("both", "sun", "sky")) -> SunskyProbe:
        """Move the emitters in ``parts`` to a new light (the others keep the old one)."""
        d = np.asarray(direction, dtype=np.float64)
        d = d / np.linalg.norm(d)
        for part in parts:
            params = self._params[part]
            params["sun_direction"] = self.mi.Vector3f(*(float(c) for c in d))
            params["turbidity"] = float(turbidity)
            params.update()
        self.direction, self.turbidity = d, float(turbidity)
        return self

    def radiance(self, directions: np.ndarray, part: str = "both") -> np.ndarray:
        """RGB radiance (N, 3) seen looking along each world direction (towards the sky)."""
        import drjit as dr

        d = np.asarray(directions, dtype=np.float32).reshape(-1, 3)
        si = dr.zeros(self.mi.SurfaceInteraction3f, len(d))
        si.wi = self.mi.Vector3f(-d[:, 0], -d[:, 1], -d[:, 2])
        value = np.array(self._emitters[part].eval(si), dtype=np.float64)
        return value.T.reshape(-1, 3)

    def sun_disk_radiance(self) -> np.ndarray:
        """RGB radiance of the sun disk (sun only, no sky), uniform over the disk."""
        return self.radiance(self.direction[None, :], "sun")[0]

    def sun_irradiance(self) -> np.ndarray:
        """RGB irradiance from the sun disk at normal incidence: radiance x solid angle."""
        return self.sun_disk_radiance() * SUN_SOLID_ANGLE_SR

    def sky_power(self, n_theta: int = 48, n_phi: int = 96) -> np.ndarray:
        """RGB integral of the sky's radiance over the upper hemisphere, W m^-2 (per sr x sr).

        Midpoint rule in (cos theta, phi), which is uniform in solid angle. A
        sphere's mean irradiance is a quarter of this, which is what makes it
        comparable with the sun's irradiance for emitter sampling weights.
        """
        values = self.radiance(_power_grid(n_theta, n_phi), "sky")
        return values.mean(axis=0) * 2.0 * math.pi

    def min_radiance(self, part: str = "both") -> np.ndarray:
        """Per-channel minimum radiance of ``part`` over the check directions."""
        values = self.radiance(hemisphere_check_directions(self.direction), part)
        return values.min(axis=0)


@cache
def _power_grid(n_theta: int, n_phi: int) -> np.ndarray:
    """The directions :meth:`SunskyProbe.sky_power` integrates over, computed once."""
    mu = (np.arange(n_theta) + 0.5) / n_theta
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2.0 * math.pi
    m, p = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1.0 - m**2)
    dirs = np.stack([s * np.cos(p), s * np.sin(p), m], -1).reshape(-1, 3)
    dirs.flags.writeable = False
    return dirs


@cache
def shared_probe(variant: str) -> SunskyProbe:
    """The process's probe for ``variant`` (built on first use).

    Not thread-safe: the probe's emitters are moved to each light in turn, so
    threads of one process must not call the emitter functions concurrently
    (the pipeline's workers are processes).
    """
    return SunskyProbe(variant)
