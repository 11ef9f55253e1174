"""Sun direction <-> (elevation, azimuth), in the project's world frame.

World frame (docs/conventions.md): z up, ground plane z = 0, camera on the -y side
looking towards +y. The sun direction is the unit vector from the scene *towards*
the sun::

    d = (cos(el) cos(az), cos(el) sin(az), sin(el))

with elevation ``el`` in degrees above the horizon and azimuth ``az`` in degrees
counter-clockwise from +x seen from above. Mitsuba's ``sunsky`` is z-up with the
same spherical convention, so ``d`` is passed to it unchanged.
"""

from __future__ import annotations

import numpy as np


def sun_direction(elevation_deg, azimuth_deg) -> np.ndarray:
    """Unit vector towards the sun, float64.

    Scalars give shape (3,); arrays broadcast and give shape (..., 3).
    """
    el = np.radians(np.asarray(elevation_deg, dtype=np.float64))
    az = np.radians(np.asarray(azimuth_deg, dtype=np.float64))
    el, az = np.broadcast_arrays(el, az)
    cos_el = np.cos(el)
    return np.stack([cos_el * np.cos(az), cos_el * np.sin(az), np.sin(el)], axis=-1)


def normalize_azimuth(azimuth_deg):
    """Wrap an azimuth in degrees into [0, 360)."""
    wrapped = np.mod(np.asarray(azimuth_deg, dtype=np.float64), 360.0)
    # fmod of a tiny negative number rounds to exactly 360.0
    wrapped = np.where(wrapped >= 360.0, 0.0, wrapped)
    return float(wrapped) if wrapped.ndim == 0 else wrapped


def sun_angles(direction):
    """(elevation_deg, azimuth_deg) of a direction towards the sun; azimuth in [0, 360).

    The direction need not be unit length. At the zenith the azimuth is undefined;
    whatever atan2 gives for the (tiny) horizontal part is returned (0 for an exact
    (0, 0, 1)). A (3,) input gives two floats, (..., 3) gives two arrays.
    """
    d = np.asarray(direction, dtype=np.float64)
    if d.shape[-1] != 3:
        raise ValueError(f"direction must have a last axis of length 3, got shape {d.shape}")
    horizontal = np.hypot(d[..., 0], d[..., 1])
    elevation = np.degrees(np.arctan2(d[..., 2], horizontal))
    azimuth = normalize_azimuth(np.degrees(np.arctan2(d[..., 1], d[..., 0])))
    if d.ndim == 1:
        return float(elevation), float(azimuth)
    return elevation, azimuth
