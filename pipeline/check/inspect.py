"""One dataset file inspected: stat, or read once, hash, decode and check its layers and
values against what the spec asks for (no record, plan or other file is consulted)."""

from __future__ import annotations

import hashlib
import json
import os
import stat
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from pipeline.check.report import Progress
from pipeline.errors import USER_ERRORS
from pipeline.image.stats import render_stats
from pipeline.store.bounded_read import UnsafePath, read_bytes, resolve_inside
from pipeline.store.exr import GEOMETRY_LAYERS, read_exr
from pipeline.store.exrheader import DEFAULT_BOUNDS, ExrBounds

#: Largest |length - 1| of a stored normal: half floats carry 11 significant bits, so a unit
#: vector rounded per component is off by up to ~1e-3 in length; measured here: <= 2.5e-4.
NORMAL_TOLERANCE = 2e-3
#: Layers of the texture-space maps file.
TEXTURE_LAYERS = ("diffuse", "specular", "roughness", "normal")
#: Channels of each map layer (pipeline.store.exr naming).
MAP_CHANNELS = {"diffuse": 3, "specular": 3, "roughness": 1, "normal": 3, "mask": 1}
#: Channels of each geometry layer a maps file may also hold (pipeline.store.exr.GEOMETRY_LAYERS).
GEOMETRY_CHANNELS = {"geometry_normal": 3, "depth": 1}
#: Layers stored as half floats when ``storage.maps_half`` (the mask and the geometry are always float32).
HALF_LAYERS = ("diffuse", "specular", "roughness", "normal")


@dataclass
class FileFacts:
    """What one read of a file showed. ``sha256`` is None when not read (fast, missing)."""

    rel: str
    size: int | None
    sha256: str | None = None
    error: str | None = None
    layers: dict[str, tuple[tuple[int, ...], str]] | None = None
    meta_json: str | None = None  # the header's metadata, kept as text: ~4x smaller than dicts
    issues: list[tuple[str, str]] = field(default_factory=list)
    pixel_stats: dict | None = None
    #: not read because it is unsafe: a symbolic link on its way, not a regular file
    #: (pipeline.store.folder); ``error`` says which.
    unsafe: bool = False

    @property
    def meta(self) -> dict | None:
        if self.meta_json is None:
            return None
        meta = json.loads(self.meta_json)
        return meta if isinstance(meta, dict) else {}

    @property
    def decoded(self) -> bool:
        return self.layers is not None

    @property
    def content_ok(self) -> bool:
        return self.size is not None and self.error is None and not self.issues


@dataclass(frozen=True)
class Expect:
    role: str
    #: name -> (channels, dtype name, or a tuple of the names allowed); None: any
    layers: dict[str, tuple[int, str | tuple[str, ...]]] | None
    shape: tuple[int, int] | None
    #: Layers the file may hold or not (checked as ``layers`` are when present): the geometry
    #: layers, to a reader that does not know which ones the spec asked for.
    optional: dict[str, tuple[int, str | tuple[str, ...]]] = field(default_factory=dict)

    @property
    def bounds(self) -> ExrBounds:
        """What the file may cost to decode (pipeline.store.exrheader): a small multiple of
        the expected image; the budget when its size or layers are not known."""
        if self.layers is None or self.shape is None:
            return DEFAULT_BOUNDS
        return ExrBounds(shape=self.shape, channels=sum(c for c, _ in (*self.layers.values(), *self.optional.values())))


def expectations(spec, material_kind: str | None, family: str | None) -> dict[str, Expect]:
    """What each role's EXR must hold, from the spec (None: only what every file needs)."""
    if spec is None:
        return {
            "render": Expect("render", {"render": (3, "float32")}, None),
            "maps": Expect("maps", None, None),
            "texture": Expect("texture", None, None),
        }
    res = (spec.render.resolution, spec.render.resolution)
    storage = spec.storage

    def dtype(name):
        return "float16" if storage.maps_half and name in HALF_LAYERS else "float32"

    channels = {**MAP_CHANNELS, **GEOMETRY_CHANNELS}
    maps = {name: (channels[name], dtype(name)) for name in storage.layers}
    texture = {name: (MAP_CHANNELS[name], dtype(name)) for name in TEXTURE_LAYERS}
    if material_kind == "uniform":
        texture_shape = (1, 1)
    elif family is not None:
        texture_shape = (spec.materials.texture_resolution,) * 2
    else:
        texture_shape = None  # imported maps keep their file's size
    return {
        "render": Expect("render", {"render": (3, "float32")}, res),
        "maps": Expect("maps", maps, res),
        "texture": Expect("texture", texture, texture_shape),
    }


def sample_expectations(resolution: int) -> dict[str, Expect]:
    """What a render and a screen-space maps file must hold when the spec is not at hand (the
    training loader reads a folder or a publication by its manifest): the layers the network
    needs at the manifest's ``resolution``; maps as half or float, either as a spec may choose;
    the geometry layers allowed, not needed."""
    either = ("float16", "float32")
    maps = {name: (MAP_CHANNELS[name], either if name in HALF_LAYERS else "float32") for name in MAP_CHANNELS}
    geometry = {name: (channels, "float32") for name, channels in GEOMETRY_CHANNELS.items()}
    texture = {name: (MAP_CHANNELS[name], either) for name in TEXTURE_LAYERS}
    return {
        "render": Expect("render", {"render": (3, "float32")}, (resolution, resolution)),
        "maps": Expect("maps", maps, (resolution, resolution), optional=geometry),
        "texture": Expect("texture", texture, None),
    }


def render_value_issues(pixels: dict) -> list[tuple[str, str]]:
    """Bad pixels of a render (its :func:`pipeline.image.stats.render_stats`): NaN or infinite
    values, negative values. Validate allows them only in a render the render policy flagged."""
    out = []
    if pixels["nan"] or pixels["inf"]:
        out.append(("non_finite", f"{pixels['nan']} NaN and {pixels['inf']} infinite value(s)"))
    if pixels["negative"]:
        out.append(("negative_render", f"{pixels['negative']} negative value(s) (min {pixels['min']:.6g})"))
    return out


def content_issues(layers: dict[str, np.ndarray], expect: Expect, flagged: bool = False) -> list[tuple[str, str]]:
    """What validate finds in one decoded file's content alone: its layers (:func:`layer_issues`),
    then a map's values (:func:`map_value_issues`) or a render's pixels (:func:`render_value_issues`,
    unless ``flagged`` by the render policy; a non-finite pixel is an issue even then: nothing
    can learn from it)."""
    issues = layer_issues(layers, expect)
    if issues:
        return issues
    if expect.role != "render":
        return map_value_issues(layers, screen_space=expect.role == "maps")
    found = render_value_issues(render_stats(layers["render"]))
    return [(kind, text) for kind, text in found if not flagged or kind == "non_finite"]


def layer_issues(layers: dict[str, np.ndarray], expect: Expect) -> list[tuple[str, str]]:
    """bad_layers issues: missing or extra layers, wrong channels, size or sample type."""
    issues = []
    if expect.layers is None:
        return issues
    missing = [n for n in expect.layers if n not in layers]
    extra = [n for n in layers if n not in expect.layers and n not in expect.optional]
    if missing:
        issues.append(("bad_layers", f"layer(s) {', '.join(missing)} missing"))
    if extra:
        issues.append(("bad_layers", f"unexpected layer(s) {', '.join(sorted(extra))}"))
    for name, (channels, dtype) in {**expect.optional, **expect.layers}.items():
        arr = layers.get(name)
        if arr is None:
            continue
        if arr.shape[2] != channels:
            issues.append(("bad_layers", f"layer {name} has {arr.shape[2]} channel(s), expected {channels}"))
        if expect.shape is not None and tuple(arr.shape[:2]) != expect.shape:
            issues.append(
                (
                    "bad_layers",
                    f"layer {name} is {arr.shape[1]}x{arr.shape[0]} pixels, "
                    f"expected {expect.shape[1]}x{expect.shape[0]}",
                )
            )
        allowed = dtype if isinstance(dtype, tuple) else (dtype,)
        if arr.dtype.name not in allowed:
            issues.append(("bad_layers", f"layer {name} is {arr.dtype.name}, expected {' or '.join(allowed)}"))
    return issues


def _range_text(values: np.ndarray) -> str:
    return f"min {float(values.min()):.6g}, max {float(values.max()):.6g}"


def map_value_issues(layers: dict[str, np.ndarray], screen_space: bool) -> list[tuple[str, str]]:
    """Sanity of material maps: finite, albedos and roughness in [0, 1], mask 0/1, unit
    normals (inside the mask for screen-space maps), nothing outside the mask; and of the
    geometry layers (:func:`geometry_value_issues`)."""
    issues = []
    inside = None
    if screen_space and "mask" in layers:
        inside = np.asarray(layers["mask"][..., 0], np.float32) > 0.5
    for name in ("diffuse", "specular", "roughness", "normal", "mask", *GEOMETRY_LAYERS):
        if name not in layers:
            continue
        values = np.asarray(layers[name], np.float32)
        finite = np.isfinite(values)
        if not finite.all():
            n_nan, n_inf = int(np.isnan(values).sum()), int(np.isinf(values).sum())
            issues.append(("non_finite", f"layer {name} has {n_nan} NaN and {n_inf} infinite value(s)"))
        values = np.where(finite, values, 0.0)
        if name in ("diffuse", "specular", "roughness"):
            bad = (values < 0) | (values > 1)
            if bad.any():
                issues.append(
                    (
                        "out_of_range",
                        f"layer {name} has {int(bad.sum())} value(s) outside [0, 1] ({_range_text(values[bad])})",
                    )
                )
        elif name == "mask":
            bad = (values != 0) & (values != 1)
            if bad.any():
                issues.append(
                    (
                        "out_of_range",
                        f"layer mask has {int(bad.sum())} value(s) other than 0 and 1 ({_range_text(values[bad])})",
                    )
                )
        elif name == "normal" and values.shape[-1] == 3 and (inside is not None or not screen_space):
            issues += _unit_issues(name, values, inside)
        elif name in GEOMETRY_LAYERS and screen_space:
            issues += geometry_value_issues(name, values, inside)
        if inside is not None and name != "mask" and values.shape[:2] == inside.shape:
            outside = np.any(values[~inside] != 0, axis=-1)
            if outside.any():
                issues.append(
                    ("out_of_range", f"layer {name} is non-zero at {int(outside.sum())} pixel(s) outside the mask")
                )
    return issues


def _unit_issues(name: str, values: np.ndarray, inside: np.ndarray | None) -> list[tuple[str, str]]:
    """normal_not_unit: pixels (inside the mask where it is known) whose 3-vector is not unit."""
    x, y, z = (values[..., i].astype(np.float64) for i in range(3))
    length = np.sqrt(x * x + y * y + z * z)  # the sum over a last axis of 3 is ~5x slower
    deviation = np.abs(length - 1.0)
    if inside is not None and inside.shape == deviation.shape:
        deviation = deviation[inside]
    bad = deviation > NORMAL_TOLERANCE
    if not bad.any():
        return []
    where = "inside the mask " if inside is not None else ""
    return [
        (
            "normal_not_unit",
            f"layer {name}: {int(bad.sum())} pixel(s) {where}not of unit length "
            f"(worst |length - 1| = {float(deviation.max()):.3g}; tolerance {NORMAL_TOLERANCE:g})",
        )
    ]


def geometry_value_issues(name: str, values: np.ndarray, inside: np.ndarray | None) -> list[tuple[str, str]]:
    """Sanity of a geometry layer (finite values already masked to 0): ``geometry_normal`` unit,
    ``depth`` > 0, where the object is seen: inside the mask, or, in a file without one, at the
    layer's non-zero pixels (outside the mask every layer is 0, which the caller checks)."""
    if inside is None or inside.shape != values.shape[:2]:
        inside = np.any(values != 0, axis=-1)
    if name == "geometry_normal" and values.shape[-1] == 3:
        return _unit_issues(name, values, inside)
    if name == "depth":
        bad = values[..., 0][inside] <= 0
        if bad.any():
            shown = _range_text(values[..., 0][inside][bad])
            return [("out_of_range", f"layer depth has {int(bad.sum())} value(s) <= 0 inside the mask ({shown})")]
    return []


def inspect_file(root: str, rel: str, expect: Expect, recorded_bytes, fast: bool) -> FileFacts:
    """Stat (fast) or read, hash, decode and check one file, reading it once."""

    try:
        path = resolve_inside(root, rel)
        info = os.lstat(path)
    except UnsafePath as exc:
        return FileFacts(rel, 0, error=exc.strerror, unsafe=True)
    except OSError:
        return FileFacts(rel, None)
    if not stat.S_ISREG(info.st_mode):
        return FileFacts(rel, info.st_size, error="not a regular file: not read", unsafe=True)
    size = info.st_size
    facts = FileFacts(rel, size)
    if fast or (recorded_bytes is not None and size != recorded_bytes):
        return facts  # a size mismatch is reported as such; its content is not the record's
    try:
        data = read_bytes(path, size)
    except UnsafePath as exc:  # swapped for a link or a FIFO since the lstat above
        facts.error, facts.unsafe = exc.strerror, True
        return facts
    except OSError as exc:
        facts.error = f"cannot be read ({exc.strerror})"
        return facts
    facts.sha256 = hashlib.sha256(data).hexdigest()
    try:
        image = read_exr(data, bounds=expect.bounds)
    except USER_ERRORS as exc:
        facts.error = str(exc).replace("<bytes>", "").replace("EXR :", "EXR:").strip()
        return facts
    facts.layers = {name: (tuple(arr.shape), arr.dtype.name) for name, arr in image.layers.items()}
    facts.meta_json = json.dumps(image.meta, separators=(",", ":"))
    facts.issues = layer_issues(image.layers, expect)
    if expect.role == "render":
        if "render" in image.layers:
            facts.pixel_stats = render_stats(image.layers["render"])
    else:
        facts.issues += map_value_issues(image.layers, screen_space=expect.role == "maps")
    return facts


def inspect_all(
    root: str,
    files: dict,
    fast: bool,
    progress,
    found: dict,
    threads,
    start,
    done_before: int = 0,
    total: int | None = None,
    bytes_before: int = 0,
) -> int:
    """Inspect ``files`` (rel path -> (owner, entry, listed_by, expectation)) on ``threads``
    threads, putting each one's facts in ``found``; return the bytes read. Progress counts
    from ``done_before`` files and ``bytes_before`` bytes towards ``total`` (default: these
    files) when files are inspected a group at a time."""
    total, bytes_read = len(files) if total is None else total, 0
    items = list(files.items())

    def one(item):
        rel, (_owner, entry, _src, expect) = item
        return inspect_file(root, rel, expect, entry.get("bytes"), fast)

    n_threads = threads or min(4, os.cpu_count() or 1)
    with ThreadPoolExecutor(max_workers=max(1, n_threads)) as pool:
        for done, facts in enumerate(pool.map(one, items), start=1):
            found[facts.rel] = facts
            if facts.sha256 is not None:
                bytes_read += facts.size or 0
            if progress is not None:
                done_all = done_before + done
                progress(
                    Progress(
                        "check",
                        done_all,
                        max(total, done_all),
                        facts.rel,
                        bytes_before + bytes_read,
                        time.perf_counter() - start,
                    )
                )
    return bytes_read
