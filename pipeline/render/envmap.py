"""HDR environment maps: read one (.exr or .hdr) as linear RGB, and light a scene with it.

The pure side (conventions, the record, rotations, the lighting vector) is
:mod:`sky.environment`; this module reads files and builds Mitsuba's ``envmap`` emitter.

- :func:`read_environment` decodes a map through the project's gates (EXR:
  :func:`pipeline.store.exr.read_exr` behind :func:`pipeline.store.exrheader.check_header`;
  Radiance: :mod:`pipeline.store.hdrfile`), within the limits declared here, and refuses a
  map that is not lat-long (``width == 2 * height``, checked from the header, before
  decoding) or holds negative, NaN or infinite radiance. Errors are
  :class:`EnvironmentMapError`, naming the file and the reason; nothing is written.
- :func:`load_environment` is the same read behind a cache keyed by the file's SHA-256, so
  a worker reads and converts a 4k map once however many samples it lights.
- :func:`environment_emitter_dict` is the scene entry: Mitsuba's ``envmap`` (which
  importance-samples the map by its luminance) with a ``to_world`` that puts the map's up
  (its local +y) on world +z and turns it about +z by the rotation, as
  :mod:`sky.environment` states the convention (tests/test_environment_numerics.py checks
  Mitsuba against :func:`sky.environment.map_direction`).
"""

from __future__ import annotations

import hashlib
import os
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from pipeline.errors import ShaderballError
from pipeline.render.mitsuba_env import load_mitsuba
from pipeline.store.bounded_read import read_bytes
from pipeline.store.exr import read_exr
from pipeline.store.exrheader import ExrBounds, ExrRefused, check_header, shown_names
from pipeline.store.hdrfile import HdrRefused, decode_hdr, max_file_bytes, read_hdr_header
from sky.environment import EnvironmentLight, check_rotation, check_scale

#: Pixels of a map read at most: an 8k lat-long map (8192 x 4096); a 4k one is a quarter of it.
MAX_ENVIRONMENT_PIXELS = 8192 * 4096
#: Width of a map read at most (its height is half of it).
MAX_ENVIRONMENT_WIDTH = 8192
#: Channels an EXR map may hold (R, G, B and an alpha, which is not used).
MAX_EXR_CHANNELS = 4
#: What an EXR map may hold, for the EXR gate: at most the largest map's pixels, float32.
ENVIRONMENT_EXR_BOUNDS = ExrBounds(
    budget_bytes=MAX_ENVIRONMENT_PIXELS * MAX_EXR_CHANNELS * 4, max_side=MAX_ENVIRONMENT_WIDTH
)
#: Bytes of a map file read at most (either format).
MAX_ENVIRONMENT_FILE_BYTES = max(
    ENVIRONMENT_EXR_BOUNDS.file_bytes, max_file_bytes(MAX_ENVIRONMENT_PIXELS, MAX_ENVIRONMENT_WIDTH)
)
#: Layers of an EXR map read as its colour: bare ``R, G, B`` channels, else one of these layers.
EXR_COLOUR_LAYERS = ("render",)
#: Maps a process keeps decoded (a 4k map is 100 MB as float32, plus its Mitsuba bitmap).
ENVIRONMENT_CACHE_ENTRIES = 2


class EnvironmentMapError(ShaderballError):
    """An environment map refused: the message names the file and the reason."""


def _refused(label: str, reason: str) -> EnvironmentMapError:
    return EnvironmentMapError(f"environment map {label}: {reason}")


def _check_lat_long(width: int, height: int, label: str) -> None:
    if width != 2 * height or height < 2:
        raise _refused(
            label,
            f"{width} x {height} pixels is not a lat-long (equirectangular) map; its width must be "
            "twice its height (at least 4 x 2)",
        )


def check_radiance(radiance, label: str) -> np.ndarray:
    """``radiance`` as a float32 (H, 2H, 3) array of finite, non-negative values, or
    :class:`EnvironmentMapError` naming ``label``, the count of bad values and the first."""
    array = np.asarray(radiance)
    if array.ndim != 3 or array.shape[2] != 3:
        raise _refused(label, f"radiance of shape {array.shape}; (height, width, 3) RGB is required")
    _check_lat_long(array.shape[1], array.shape[0], label)
    array = array.astype(np.float32, copy=False)
    bad = ~(np.isfinite(array) & (array >= 0.0))
    if bad.any():
        rows, cols = np.nonzero(bad.any(axis=2))
        first = [float(v) for v in array[rows[0], cols[0]]]
        raise _refused(
            label,
            f"{rows.size} pixel(s) with negative, NaN or infinite radiance (the first at row "
            f"{rows[0]}, column {cols[0]}: {first}); radiance must be finite and >= 0",
        )
    return array


def _exr_colour(layers: dict[str, np.ndarray], label: str) -> np.ndarray:
    """The RGB of an EXR map's decoded layers: bare R, G, B channels, or a colour layer."""
    if all(c in layers for c in "RGB"):
        return np.concatenate([layers[c] for c in "RGB"], axis=2)
    for name in EXR_COLOUR_LAYERS:
        if name in layers and layers[name].shape[2] == 3:
            return layers[name]
    allowed = (
        "R, G, B channels (and an optional A) or a " + " / ".join(f"{n}.R/G/B" for n in EXR_COLOUR_LAYERS) + " layer"
    )
    raise _refused(label, f"its layers are {shown_names(sorted(layers))}; {allowed} is required")


def _decode_exr(data: bytes, label: str) -> np.ndarray:
    try:
        header = check_header(data, label, ENVIRONMENT_EXR_BOUNDS)
    except ExrRefused as exc:
        raise _refused(label, exc.reason) from None
    _check_lat_long(header.width, header.height, label)
    if any(kind == 0 for kind in header.channels.values()):
        raise _refused(label, "it holds integer (UINT) channels; half or float channels are required")
    try:
        layers = read_exr(data, label, ENVIRONMENT_EXR_BOUNDS).layers
    except ShaderballError as exc:
        raise _refused(label, str(exc)) from None
    return _exr_colour(layers, label)


def _decode_hdr(data: bytes, label: str) -> np.ndarray:
    limits = {"max_pixels": MAX_ENVIRONMENT_PIXELS, "max_side": MAX_ENVIRONMENT_WIDTH}
    try:
        header = read_hdr_header(data, label, **limits)
        _check_lat_long(header.width, header.height, label)
        return decode_hdr(data, label, **limits)
    except HdrRefused as exc:
        raise _refused(label, exc.reason) from None


def _read_file(path) -> tuple[str, bytes]:
    label = os.fspath(path)
    suffix = os.path.splitext(label)[1].lower()
    if suffix not in (".exr", ".hdr"):
        raise _refused(label, f"suffix {suffix!r}; .exr or .hdr is required")
    try:
        return label, read_bytes(label, MAX_ENVIRONMENT_FILE_BYTES)
    except OSError as exc:
        raise _refused(label, exc.strerror or str(exc)) from None


def decode_environment(data: bytes, label: str) -> np.ndarray:
    """The map file ``data`` (its name ``label`` picks the format by suffix) as checked
    float32 (H, 2H, 3) linear RGB radiance."""
    decode = _decode_exr if label.lower().endswith(".exr") else _decode_hdr
    return check_radiance(decode(data, label), label)


def read_environment(path) -> np.ndarray:
    """The environment map at ``path`` (.exr or .hdr) as float32 (H, 2H, 3) linear RGB,
    row 0 the zenith; :class:`EnvironmentMapError` naming the file and the reason."""
    label, data = _read_file(path)
    return decode_environment(data, label)


@dataclass(frozen=True)
class LoadedEnvironment:
    """A decoded map (read-only) and the SHA-256 of the bytes it was decoded from."""

    digest: str
    radiance: np.ndarray


class _Cache:
    """The last :data:`ENVIRONMENT_CACHE_ENTRIES` maps decoded, by digest, each with the Mitsuba
    bitmaps made of it (by variant). Shared by the threads of a worker."""

    def __init__(self, entries: int):
        self.entries = entries
        self.lock = threading.Lock()
        self.maps: OrderedDict[str, tuple[LoadedEnvironment, dict]] = OrderedDict()

    def get(self, digest: str):
        with self.lock:
            if digest in self.maps:
                self.maps.move_to_end(digest)
                return self.maps[digest][0]
            return None

    def put(self, loaded: LoadedEnvironment) -> LoadedEnvironment:
        with self.lock:
            self.maps[loaded.digest] = (loaded, {})
            while len(self.maps) > self.entries:
                self.maps.popitem(last=False)
        return loaded

    def bitmap(self, radiance: np.ndarray, variant: str, make):
        """The bitmap of ``radiance`` under ``variant``: the cached one if ``radiance`` is a cached
        map's own array, else a new one (not kept: an array not from the cache has no digest)."""
        with self.lock:
            entry = next((e for e in self.maps.values() if e[0].radiance is radiance), None)
            if entry is not None and variant in entry[1]:
                return entry[1][variant]
        made = make(radiance)
        if entry is not None:
            with self.lock:
                entry[1][variant] = made
        return made

    def clear(self) -> None:
        with self.lock:
            self.maps.clear()


_CACHE = _Cache(ENVIRONMENT_CACHE_ENTRIES)


#: (path, size, mtime_ns, inode) -> the SHA-256 of the bytes read there: a file whose status
#: is unchanged is not read and hashed again (a 4k EXR is ~0.2 s of reading and hashing, per
#: render without this); any write to it changes its mtime, and so its key.
_STAT_DIGESTS: dict[tuple, str] = {}


def _stat_key(path) -> tuple | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (os.fspath(path), st.st_size, st.st_mtime_ns, st.st_ino)


def load_environment(path) -> LoadedEnvironment:
    """The map at ``path`` and its digest, read once: the file is read and hashed again only
    when its status (size, modification time, inode) changed since it was last read, and
    decoded only when its digest is not among the cached ones."""
    key = _stat_key(path)
    known = _STAT_DIGESTS.get(key) if key is not None else None
    cached = _CACHE.get(known) if known is not None else None
    if cached is not None:
        return cached
    label, data = _read_file(path)
    digest = hashlib.sha256(data).hexdigest()
    if key is not None and key == _stat_key(path):  # not rewritten while it was read
        _STAT_DIGESTS[key] = digest
    cached = _CACHE.get(digest)
    if cached is not None:
        return cached
    radiance = decode_environment(data, label)
    del data
    radiance.flags.writeable = False
    return _CACHE.put(LoadedEnvironment(digest=digest, radiance=radiance))


def clear_environment_cache() -> None:
    """Forget every cached map (tests; a worker that lit its last sample with maps)."""
    _CACHE.clear()
    _STAT_DIGESTS.clear()


def environment_to_world(rotation_deg: float, variant: str):
    """The ``to_world`` of an ``envmap``: its local +y (the map's up) on world +z, its local
    +z (the map's centre, ``u = 0.5``) on world +y, then turned by ``rotation_deg`` about +z."""
    mi = load_mitsuba(variant)
    T = mi.ScalarTransform4f
    upright = T().look_at(origin=[0.0, 0.0, 0.0], target=[0.0, 1.0, 0.0], up=[0.0, 0.0, 1.0])
    composed = T().rotate(axis=[0.0, 0.0, 1.0], angle=float(rotation_deg)) @ upright
    # Its inverse as Mitsuba recomputes it where a loaded envmap's to_world is set (vectorised
    # float32, from the matrix), not as the composition gives it (an ulp apart at some angles,
    # measured): a scene moved to this rotation in place and one loaded for it hold the same
    # bits (pipeline.render.lights.move_light).
    inverse = np.array(mi.AffineTransform4f(composed.matrix).inverse_transpose, dtype=np.float32).reshape(4, 4)
    return T(mi.ScalarMatrix4f(np.array(composed.matrix, dtype=np.float32)), mi.ScalarMatrix4f(inverse))


def environment_emitter_dict(radiance: np.ndarray, rotation_deg: float, scale: float, *, variant: str) -> dict:
    """The Mitsuba ``envmap`` plugin dict of a map (float32 (H, 2H, 3), finite, >= 0),
    turned by ``rotation_deg`` about +z and multiplied by ``scale``. The map's bitmap is
    made once per cached map (:func:`load_environment`) and variant."""
    mi = load_mitsuba(variant)
    rotation_deg, scale = check_rotation(rotation_deg), check_scale(scale)

    def make(array):  # a writable copy: Mitsuba's Bitmap takes no read-only array (a cached map is one)
        return mi.Bitmap(np.array(check_radiance(array, "<radiance>"), dtype=np.float32, order="C", copy=True))

    return {
        "type": "envmap",
        "bitmap": _CACHE.bitmap(radiance, variant, make),
        "scale": scale,
        "to_world": environment_to_world(rotation_deg, variant),
    }


def environment_light_dict(light: EnvironmentLight, *, variant: str) -> dict:
    """The ``envmap`` entry of a sample's :class:`sky.environment.EnvironmentLight`, read
    through the cache; refused if the file's bytes are no longer those the light records."""
    loaded = load_environment(light.file)
    if loaded.digest != light.digest:
        raise _refused(
            light.file,
            f"its SHA-256 is {loaded.digest}, not the {light.digest} recorded when the lighting was "
            "planned: the file changed since (restore it, or plan again)",
        )
    return environment_emitter_dict(loaded.radiance, light.rotation_deg, light.scale, variant=variant)
