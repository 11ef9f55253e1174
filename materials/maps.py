"""The four maps of a material, and the normal-map encodings.

Layout (docs/conventions.md): (H, W, C) float32, row 0 at the top, texel
(i, j) centred at ``u = (j + 0.5) / W``, ``v = (i + 0.5) / H``.

Tangent frame of ``normal``: x towards increasing column (+u), y towards the
top of the picture (decreasing row), z out of the surface. This is the frame
of Mitsuba's ``normalmap`` (x along dp/du, y = n x x) when the picture is put
on the surface unmirrored, and the frame of Deschaintre et al.'s files (their
surface has x to the right and y up, "-1 in the bottom of the table").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from materials.errors import MaterialError, number_allowed, refusal, triple_allowed

#: A map's unit normal may be off unit length by this much (8-bit imports are renormalised).
NORMAL_UNIT_TOLERANCE = 1e-3
#: An albedo, diffuse or specular, each linear RGB channel: declared here once (the spec's,
#: the commands' and the server's rules are built from it).
ALBEDO_RANGE = (0.0, 1.0)
#: Roughness r (GGX alpha = r^2).
ROUGHNESS_RANGE = (0.0, 1.0)


def _as_resolution(resolution) -> tuple[int, int]:
    if isinstance(resolution, (int, np.integer)):
        height = width = int(resolution)
    else:
        try:
            height, width = (int(x) for x in resolution)
        except (TypeError, ValueError):
            raise MaterialError(f"resolution: {resolution!r} is not an int or a (height, width) pair") from None
    if height < 1 or width < 1:
        raise MaterialError(f"resolution: {resolution!r} must be positive")
    return height, width


def _frozen_array(name: str, value, shape_tail: tuple[int, ...]) -> np.ndarray:
    array = np.array(value, dtype=np.float32, copy=True, order="C")
    expected_ndim = 2 + len(shape_tail)
    if array.ndim != expected_ndim or array.shape[2:] != shape_tail:
        want = "(H, W" + "".join(f", {n}" for n in shape_tail) + ")"
        raise MaterialError(f"MaterialMaps.{name}: shape {array.shape} is not {want}")
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class UniformMaterial:
    """One value per map: the paper's uniform materials.

    ``diffuse`` and ``specular`` are linear RGB albedos in :data:`ALBEDO_RANGE`,
    ``roughness`` in :data:`ROUGHNESS_RANGE` (alpha = roughness^2), ``normal`` a
    tangent-space direction with z > 0 (normalised here).
    """

    diffuse: tuple[float, float, float]
    specular: tuple[float, float, float]
    roughness: float
    normal: tuple[float, float, float] = (0.0, 0.0, 1.0)

    def __post_init__(self):
        object.__setattr__(self, "diffuse", tuple(float(c) for c in self.diffuse))
        object.__setattr__(self, "specular", tuple(float(c) for c in self.specular))
        object.__setattr__(self, "roughness", float(self.roughness))
        n = np.asarray(self.normal, dtype=np.float64)
        length = float(np.linalg.norm(n)) if n.shape == (3,) else 0.0
        if n.shape != (3,) or not np.isfinite(length) or length == 0.0 or n[2] <= 0.0:
            raise refusal("UniformMaterial.normal", self.normal, "a finite 3-vector with z > 0")
        object.__setattr__(self, "normal", tuple(float(c) for c in n / length))
        lo, hi = ALBEDO_RANGE
        for name in ("diffuse", "specular"):
            value = getattr(self, name)
            if len(value) != 3 or not all(np.isfinite(c) and lo <= c <= hi for c in value):
                raise refusal(f"UniformMaterial.{name}", value, triple_allowed(lo, hi))
        lo, hi = ROUGHNESS_RANGE
        if not (np.isfinite(self.roughness) and lo <= self.roughness <= hi):
            raise refusal("UniformMaterial.roughness", self.roughness, number_allowed(lo, hi))

    def to_maps(self, resolution) -> MaterialMaps:
        """Replicate the values into maps of ``resolution`` (int or (H, W))."""
        height, width = _as_resolution(resolution)

        def fill(value, channels):
            shape = (height, width) if channels == 0 else (height, width, channels)
            return np.broadcast_to(np.asarray(value, dtype=np.float32), shape)

        return MaterialMaps(
            diffuse=fill(self.diffuse, 3),
            specular=fill(self.specular, 3),
            roughness=fill(self.roughness, 0),
            normal=fill(self.normal, 3),
        )

    def as_dict(self) -> dict:
        """Plain values for a manifest (JSON/TOML)."""
        return {
            "diffuse": list(self.diffuse),
            "specular": list(self.specular),
            "roughness": self.roughness,
            "normal": list(self.normal),
        }


@dataclass(frozen=True, eq=False)
class MaterialMaps:
    """A material: four texture-space maps (float32, read-only copies).

    ``diffuse`` (H, W, 3) and ``specular`` (H, W, 3) linear albedos in [0, 1];
    ``roughness`` (H, W) in [0, 1]; ``normal`` (H, W, 3) unit tangent-space
    normals with z > 0 (frame in the module docstring). Construction checks
    shapes only; :meth:`check` checks values.
    """

    diffuse: np.ndarray
    specular: np.ndarray
    roughness: np.ndarray
    normal: np.ndarray

    def __post_init__(self):
        for name, tail in (("diffuse", (3,)), ("specular", (3,)), ("roughness", ()), ("normal", (3,))):
            object.__setattr__(self, name, _frozen_array(name, getattr(self, name), tail))
        shapes = {name: getattr(self, name).shape[:2] for name in ("diffuse", "specular", "roughness", "normal")}
        if len(set(shapes.values())) != 1:
            raise MaterialError(f"MaterialMaps: maps differ in resolution: {shapes}")

    @property
    def resolution(self) -> tuple[int, int]:
        """(height, width) in texels."""
        return tuple(int(x) for x in self.roughness.shape)

    def is_uniform(self) -> bool:
        """True when every map holds one value (bit-identical texels)."""
        return all(
            bool(np.all(m == m.reshape(-1, *m.shape[2:])[0]))
            for m in (self.diffuse, self.specular, self.roughness, self.normal)
        )

    def uniform_values(self) -> UniformMaterial | None:
        """The single values as a :class:`UniformMaterial` when uniform, else None."""
        if not self.is_uniform():
            return None
        return UniformMaterial(
            diffuse=tuple(self.diffuse[0, 0]),
            specular=tuple(self.specular[0, 0]),
            roughness=float(self.roughness[0, 0]),
            normal=tuple(self.normal[0, 0]),
        )

    def check(self) -> MaterialMaps:
        """Raise :class:`MaterialError` naming the map, texel and value that is bad; else self."""
        for name in ("diffuse", "specular", "roughness"):
            values = getattr(self, name)
            bad = ~np.isfinite(values) | (values < 0.0) | (values > 1.0)
            if bad.any():
                index = tuple(int(i) for i in np.argwhere(bad)[0])
                raise MaterialError(
                    f"material map {name}: value {float(values[index])!r} at {index} is not finite and in [0, 1]"
                )
        n = self.normal
        finite = np.all(np.isfinite(n), axis=-1)
        length = np.linalg.norm(np.where(finite[..., None], n, 0.0), axis=-1)
        bad = ~finite | (np.abs(length - 1.0) > NORMAL_UNIT_TOLERANCE) | (n[..., 2] <= 0.0)
        if bad.any():
            index = tuple(int(i) for i in np.argwhere(bad)[0])
            raise MaterialError(
                f"material map normal: value {n[index].tolist()!r} at {index} is not a unit "
                f"vector (|n| - 1 within {NORMAL_UNIT_TOLERANCE}) with z > 0"
            )
        return self

    def tobytes(self) -> bytes:
        """All four maps' bytes, for reproducibility checks and checksums."""
        return b"".join(m.tobytes() for m in (self.diffuse, self.specular, self.roughness, self.normal))


def encode_normal_map(normal: np.ndarray) -> np.ndarray:
    """Tangent-space unit normals (..., 3) to the [0, 1] colours Mitsuba's ``normalmap`` expects.

    ``(n + 1) / 2`` per component, float32; use the result in a ``bitmap``
    texture with ``raw: True``.
    """
    n = np.asarray(normal, dtype=np.float32)
    return np.clip((n + 1.0) * 0.5, 0.0, 1.0).astype(np.float32)


def decode_normal_map(encoded: np.ndarray, *, min_z: float = 1e-3) -> tuple[np.ndarray, int]:
    """Colours in [0, 1] (..., 3) to unit normals with z >= ``min_z``; also the count of repairs.

    ``2 c - 1`` per component, normalised. A texel that decodes to a
    zero-length vector becomes (0, 0, 1); one with ``z < min_z`` (on or below
    the tangent plane, which a height field cannot produce) gets ``z = min_z``
    before normalising. Both are counted as repairs.
    """
    n = 2.0 * np.asarray(encoded, dtype=np.float64) - 1.0
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    zero = length[..., 0] < 1e-6
    n = np.where(zero[..., None], np.array([0.0, 0.0, 1.0]), n / np.where(zero[..., None], 1.0, length))
    low = n[..., 2] < min_z
    n[..., 2] = np.maximum(n[..., 2], min_z)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return n.astype(np.float32), int(np.count_nonzero(zero | low))


def normals_from_height(height: np.ndarray, depth: float) -> np.ndarray:
    """Unit tangent-space normals of a periodic height field.

    ``height`` (H, W) in [0, 1] is scaled by ``depth``, in units of the
    texture's side (the texture spans 1 x 1), so the same surface gives the
    same normals at any resolution. Central differences with wrap-around keep
    the result tileable. Frame: x = +u (columns), y = up the picture.
    """
    h = np.asarray(height, dtype=np.float64) * float(depth)
    rows, cols = h.shape
    dh_du = (np.roll(h, -1, axis=1) - np.roll(h, 1, axis=1)) * (cols / 2.0)
    dh_drow = (np.roll(h, -1, axis=0) - np.roll(h, 1, axis=0)) * (rows / 2.0)
    # y points up the picture, i.e. towards decreasing row: dh/dy = -dh/drow.
    n = np.stack([-dh_du, dh_drow, np.ones_like(h)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return n.astype(np.float32)


def tilt_normal(tilt_deg: float, azimuth_deg: float) -> tuple[float, float, float]:
    """The unit normal tilted ``tilt_deg`` from z towards azimuth ``azimuth_deg`` (from +x to +y)."""
    t, a = np.radians(tilt_deg), np.radians(azimuth_deg)
    return (float(np.sin(t) * np.cos(a)), float(np.sin(t) * np.sin(a)), float(np.cos(t)))
