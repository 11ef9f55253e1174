"""The one place that reads and writes EXR files.

Layers follow OpenEXR's naming (`render.R`, `diffuse.G`, `roughness.Y`, `normal.X`, ...),
so any EXR viewer shows them. Files are written to memory, then atomically to disk
(:mod:`pipeline.store.atomic`), with linear Rec.709 chromaticities in the header. Nothing
run-dependent (time, host) goes into a file: the same pixels give the same bytes.
"""

from __future__ import annotations

import ctypes
import io
import json
import os
import sys
import threading
from dataclasses import dataclass

import numpy as np

from pipeline.errors import ShaderballError
from pipeline.image.formats import EXR_COMPRESSIONS
from pipeline.store.atomic import write_bytes_atomic
from pipeline.store.bounded_read import read_bytes
from pipeline.store.exrheader import DEFAULT_BOUNDS, ExrBounds, ExrHeader, ExrRefused, check_header, shown_names

#: Channel suffixes per layer; a layer not listed here with C channels uses "0".."C-1".
LAYER_CHANNELS: dict[str, tuple[str, ...]] = {
    "render": ("R", "G", "B"),
    "diffuse": ("R", "G", "B"),
    "specular": ("R", "G", "B"),
    "checker": ("R", "G", "B"),
    "roughness": ("Y",),
    "mask": ("Y",),
    "normal": ("X", "Y", "Z"),
    "uv": ("U", "V"),
    "geometry_normal": ("X", "Y", "Z"),
    "depth": ("Z",),
}

#: A material's four maps: the layers of its texture-space file, and the layers stored as half
#: floats when ``storage.maps_half`` is on (the mask and the renders stay float32).
MATERIAL_MAP_LAYERS: tuple[str, ...] = ("diffuse", "specular", "roughness", "normal")
#: The object's geometry under the maps (world-space shading normal, z-depth in metres): layers
#: a maps file may hold besides the maps (the spec's ``storage.layers`` names them the same way:
#: pipeline.dataset.spec.GEOMETRY_LAYERS; a test holds the two equal). Always float32, even with
#: ``storage.maps_half``: half floats keep 11 significant bits, so a depth is rounded to steps of
#: 2 mm between 2 and 4 m, 4 mm between 4 and 8 m: too coarse for what a depth buffer is used
#: for (edges, normals recomputed from it).
GEOMETRY_LAYERS: tuple[str, ...] = ("geometry_normal", "depth")
#: Bytes per channel value of a layer stored as float32 and as half.
FLOAT_BYTES, HALF_BYTES = 4, 2


def pixel_bytes(layers, side: int, half: tuple[str, ...] = ()) -> int:
    """Bytes of pixel data of a ``side`` x ``side`` file of ``layers``, as :func:`encode_exr` lays
    them out before compression (headers and compression not counted)."""
    per_pixel = sum(len(LAYER_CHANNELS[name]) * (HALF_BYTES if name in half else FLOAT_BYTES) for name in layers)
    return side * side * per_pixel


#: The layers each role's file may hold (a maps file holds those storage.layers names).
ROLE_LAYERS: dict[str, tuple[str, ...]] = {
    "render": ("render",),
    "maps": (*MATERIAL_MAP_LAYERS, "mask", *GEOMETRY_LAYERS),
    "texture": MATERIAL_MAP_LAYERS,
}


#: Linear Rec.709 / sRGB primaries and D65 white: red xy, green xy, blue xy, white xy.
REC709_CHROMATICITIES = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)

#: Header attribute holding JSON metadata written by shaderball.
META_KEY = "shaderball"


@dataclass(frozen=True)
class ExrImage:
    """Decoded layers (each (H, W, C), C >= 1) and the JSON metadata of a file."""

    layers: dict[str, np.ndarray]
    meta: dict
    chromaticities: tuple[float, ...] | None


def channel_names(layer: str, n_channels: int) -> tuple[str, ...]:
    names = LAYER_CHANNELS.get(layer)
    if names is None or len(names) != n_channels:
        if n_channels == 1:
            return ("Y",)
        names = tuple(str(i) for i in range(n_channels))
    return names


def encode_exr(
    layers: dict[str, np.ndarray],
    meta: dict | None = None,
    *,
    half: tuple[str, ...] = (),
    compression: str = "zip",
) -> bytes:
    """Encode ``layers`` (name -> (H, W) or (H, W, C) array) as EXR bytes.

    Layers named in ``half`` are stored as float16, the others as float32.
    """
    import OpenEXR

    if compression not in EXR_COMPRESSIONS:
        # the spec's storage.compression is checked by its field rule: another value here is a bug
        raise ValueError(f"compression {compression!r}: not one of {', '.join(EXR_COMPRESSIONS)}")
    channels: dict[str, np.ndarray] = {}
    shape = None
    for layer, array in layers.items():
        arr = np.asarray(array)
        if arr.ndim == 2:
            arr = arr[:, :, None]
        if arr.ndim != 3:
            raise ValueError(f"layer {layer!r} must be (H, W) or (H, W, C), got {arr.shape}")
        if shape is None:
            shape = arr.shape[:2]
        elif arr.shape[:2] != shape:
            raise ValueError(f"layer {layer!r} has shape {arr.shape[:2]}, others {shape}")
        dtype = np.float16 if layer in half else np.float32
        for i, suffix in enumerate(channel_names(layer, arr.shape[2])):
            channels[f"{layer}.{suffix}"] = np.ascontiguousarray(arr[:, :, i], dtype=dtype)
    header = {
        "compression": getattr(OpenEXR, EXR_COMPRESSIONS[compression]),
        "type": OpenEXR.scanlineimage,
        "chromaticities": REC709_CHROMATICITIES,
        META_KEY: json.dumps(meta or {}, sort_keys=True, separators=(",", ":")),
    }
    buffer = io.BytesIO()
    OpenEXR.File(header, channels).write(buffer)
    return buffer.getvalue()


def write_exr(path: str, layers: dict[str, np.ndarray], meta: dict | None = None, **kwargs) -> str:
    """Write an EXR atomically (temp file, fsync, rename); return its SHA-256."""
    return write_bytes_atomic(path, encode_exr(layers, meta, **kwargs))


class _StdoutToStderr:
    """While inside, the process's file descriptor 1 is its stderr. OpenEXR's C++ core prints
    warnings (``Warning: Exception raised reading pixel data ...``) on stdout when it reads a
    corrupt file, and stdout carries machine-readable output (``validate --json``): the
    library's words go to stderr instead. Counted, so threads decoding at once share one
    redirection; C's stdio buffers are flushed before fd 1 is given back."""

    _lock = threading.Lock()
    _depth = 0
    _saved: int | None = None

    def __enter__(self):
        with self._lock:
            if _StdoutToStderr._depth == 0:
                sys.stdout.flush()
                _StdoutToStderr._saved = os.dup(1)
                os.dup2(2, 1)
            _StdoutToStderr._depth += 1

    def __exit__(self, *exc):
        with self._lock:
            _StdoutToStderr._depth -= 1
            if _StdoutToStderr._depth == 0:
                _flush_c_stdio()
                os.dup2(_StdoutToStderr._saved, 1)
                os.close(_StdoutToStderr._saved)
                _StdoutToStderr._saved = None


def _flush_c_stdio() -> None:
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):
        pass


def layer_bounds(side: int | None, layers, *, exact: bool = False) -> ExrBounds:
    """The bounds of a file expected to hold ``layers`` (names of :data:`LAYER_CHANNELS`) at
    ``side`` x ``side`` pixels (None: any size within the budget)."""
    channels = sum(len(LAYER_CHANNELS.get(name, ("Y",))) for name in layers)
    return ExrBounds(shape=None if side is None else (side, side), channels=channels, exact=exact)


def openexr_reading(data: bytes) -> tuple[int, int, list[str]]:
    """(width, height, sorted channel names) of the EXR ``data`` as OpenEXR itself reads its
    header (no pixel decoded): what :func:`read_exr` compares with the gate's reading."""
    import OpenEXR

    with _StdoutToStderr():
        probe = OpenEXR.File(io.BytesIO(data), header_only=True)
        header = probe.header()
    (x_min, y_min), (x_max, y_max) = (tuple(int(v) for v in corner) for corner in header["dataWindow"])
    return x_max - x_min + 1, y_max - y_min + 1, sorted(c.name for c in header["channels"])


def _agree(data: bytes, gate: ExrHeader, label: str) -> None:
    """Refuse the file unless OpenEXR reads the window and channel list the gate read."""
    try:
        width, height, names = openexr_reading(data)
    except Exception as exc:  # the bindings raise plain exceptions for corrupt files
        raise ShaderballError(f"cannot decode EXR {label}: {exc}") from None
    if (width, height, names) != (gate.width, gate.height, sorted(gate.channels)):
        raise ShaderballError(
            f"cannot decode EXR {label}: OpenEXR reads its header as {width} x {height} pixels of "
            f"{shown_names(names)} channel(s), not the {gate.width} x {gate.height} of "
            f"{shown_names(sorted(gate.channels))} it was checked as"
        )


def read_exr(
    path_or_bytes: str | bytes | os.PathLike, label: str | None = None, bounds: ExrBounds = DEFAULT_BOUNDS
) -> ExrImage:
    """Decode an EXR written by :func:`write_exr` (or any layered EXR) into layers. Its header
    is checked against ``bounds`` first (:func:`pipeline.store.exrheader.check_header`): a
    file that would decode to more, or that is tiled, deep or multi-part, is refused before
    OpenEXR sees it; then OpenEXR reads the header alone, and a file it reads otherwise than
    the gate did (another window or channel list) is refused before any pixel is decoded.
    What OpenEXR prints while it decodes goes to stderr, never stdout
    (:class:`_StdoutToStderr`). ``label`` names the file in errors (given bytes, pass the
    file they were read from)."""
    import OpenEXR

    if label is None:
        label = "<bytes>" if isinstance(path_or_bytes, bytes) else str(path_or_bytes)
    if isinstance(path_or_bytes, bytes):
        data = path_or_bytes
    else:
        try:  # no larger than a file of ``bounds`` can be (a file grown in place is not read)
            data = read_bytes(os.fspath(path_or_bytes), bounds.file_bytes)
        except OSError as exc:
            raise ShaderballError(f"cannot decode EXR {label}: {exc.strerror or exc}") from None
    try:
        gate = check_header(data, label, bounds)
    except ExrRefused as exc:
        raise ShaderballError(f"cannot decode EXR {label}: {exc.reason}") from None
    _agree(data, gate, label)
    try:
        with _StdoutToStderr():
            handle = OpenEXR.File(io.BytesIO(data), separate_channels=True)
            header = handle.header()
            channels = {name: channel.pixels for name, channel in handle.channels().items()}
            del handle  # the channels' arrays are held by ``channels`` alone: each goes once stacked
    except Exception as exc:  # the bindings raise plain exceptions for corrupt files
        raise ShaderballError(f"cannot decode EXR {label}: {exc}") from exc
    grouped: dict[str, dict[str, str]] = {}  # layer -> suffix -> the channel's full name
    for full_name in channels:
        layer, _, suffix = full_name.rpartition(".")
        grouped.setdefault(layer or full_name, {})[suffix] = full_name
    layers = {}
    for layer, chans in grouped.items():
        order = LAYER_CHANNELS.get(layer)
        if order is None or set(order) != set(chans):
            order = tuple(sorted(chans))
        layers[layer] = np.stack([channels[chans[c]] for c in order], axis=-1)
        for full_name in chans.values():  # stacked: its arrays go (peak: the file plus one layer)
            channels.pop(full_name, None)
    meta_text = header.get(META_KEY)
    try:
        meta = json.loads(meta_text) if isinstance(meta_text, str) and meta_text else {}
    except (ValueError, RecursionError):
        raise ShaderballError(f"cannot decode EXR {label}: its {META_KEY} attribute is not JSON") from None
    chroma = header.get("chromaticities")
    return ExrImage(layers=layers, meta=meta, chromaticities=tuple(chroma) if chroma else None)
