"""A view's material as texture-space maps: uniform values, a procedural SVBRDF, a dataset
sample (made again from the dataset's spec and plan), or maps the page uploaded or painted.

Uploads are bounded before they are decoded: the body's bytes by the server, then the
image's pixel count from its header (Pillow's lazy open, OpenEXR's header-only read), and
only then the pixels. Memory is bounded across all clients at once, not per upload alone: a
130 kB 16-bit PNG of 4096 x 4096 pixels decodes to hundreds of MB, so 16 decoded at once
would take gigabytes. Each decode reserves its worst case (:data:`DECODE_BYTES_PER_PIXEL`
times the pixels its header gives) from one :data:`DECODE_BUDGET_BYTES` shared by every
upload; one past the budget waits for others to finish (up to :data:`DECODE_WAIT_S`, then
503). A decode keeps only what the renderer uses: each channel is resampled to
TEXTURE_TEXELS a side as it is converted, never the whole image as float. A dataset sample is
picked by its id, which must be in the dataset's manifest; the id never becomes a path.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import threading

import numpy as np

from materials import MaterialMaps, UniformMaterial, decode_normal_map, sample_svbrdf
from materials.errors import MaterialError
from materials.imagefile import read_image
from pipeline.dataset.materialize import make_material
from pipeline.dataset.plan import list_imported_maps, plan_dataset, seeded_rng
from pipeline.dataset.spec_file import parse_spec
from pipeline.errors import USER_ERRORS, ShaderballError
from pipeline.fields import FieldError
from pipeline.fields.rules import format_value
from pipeline.publish.names import DATASET_DIR, INDEX_FILE
from pipeline.serve.view import (
    MAP_NAMES,
    SAMPLE_ID,
    DatasetChoice,
    MapsChoice,
    RequestError,
    SvbrdfChoice,
    UniformChoice,
    UploadRequest,
    with_status,
)
from pipeline.store.bounded_read import read_bytes
from pipeline.store.exr import read_exr
from pipeline.store.exrheader import ExrBounds, ExrRefused, check_header
from pipeline.store.folder import read_manifest
from pipeline.store.layout import SPEC_FILE, Layout

#: Largest upload body, bytes.
MAX_UPLOAD_BYTES = 8 * 1024 * 1024
#: Largest upload, pixels (width x height, from the header, before decoding).
MAX_UPLOAD_PIXELS = 4096 * 4096
#: Uploaded maps are resampled to this many texels a side (the paper's canvases: 200).
TEXTURE_TEXELS = 256
#: Procedural SVBRDFs at this texture resolution (smoke spec: 64; the ball covers <= 128 px here).
SVBRDF_TEXELS = 128
#: An uploaded EXR: at most MAX_UPLOAD_PIXELS of up to 4 float channels, checked from its header.
UPLOAD_EXR_BOUNDS = ExrBounds(budget_bytes=MAX_UPLOAD_PIXELS * 4 * 4)
#: Memory one decode may take per pixel of its image, worst case: Pillow's decoded image (4 B)
#: beside its numpy copy (up to 4 B a channel of 3: 16-bit grey comes as int32) and one channel
#: as float32 (4 B); an EXR's float channels twice (OpenEXR's and ours). Measured: about 11 B
#: (a 16-bit 4096 x 4096 PNG: 180 MB at its peak).
DECODE_BYTES_PER_PIXEL = 32
#: Bytes all uploads decoding at once may reserve together; a worst-case upload (4096 x 4096
#: pixels: 512 MiB reserved, the budget whole) decodes alone, small ones side by side.
DECODE_BUDGET_BYTES = 512 * 1024 * 1024
#: Seconds an upload waits for its share of the decode budget before it is refused (503).
DECODE_WAIT_S = 120.0
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
EXR_MAGIC = b"\x76\x2f\x31\x01"
#: Most renders of a dataset the picker lists (its manifest is read whole, bounded by this count).
MAX_PICKER_SAMPLES = 100_000


def uniform_maps(choice: UniformChoice) -> MaterialMaps:
    tilt = math.radians(choice.tilt_deg)
    normal = (math.sin(tilt), 0.0, math.cos(tilt))
    if choice.metal:  # a metal: no diffuse lobe, a coloured specular albedo
        material = UniformMaterial((0.0, 0.0, 0.0), choice.diffuse, choice.roughness, normal)
    else:
        material = UniformMaterial(choice.diffuse, (choice.specular,) * 3, choice.roughness, normal)
    return material.to_maps(1)


def svbrdf_maps(choice: SvbrdfChoice) -> MaterialMaps:
    return sample_svbrdf(seeded_rng(choice.seed), choice.family, SVBRDF_TEXELS)


class DecodeBudget:
    """Bytes of memory reserved by the decodes under way, shared by every client."""

    def __init__(self, total: int):
        self.total, self.used = total, 0
        self.cond = threading.Condition()

    @contextlib.contextmanager
    def reserve(self, nbytes: int, label: str, wait_s: float = DECODE_WAIT_S):
        nbytes = min(nbytes, self.total)  # the largest allowed decodes alone
        with self.cond:
            if not self.cond.wait_for(lambda: self.used + nbytes <= self.total, wait_s):
                raise RequestError(f"{label}: the server is decoding other uploads; send it again shortly", 503)
            self.used += nbytes
        try:
            yield
        finally:
            with self.cond:
                self.used -= nbytes
                self.cond.notify_all()


#: The one budget of the server's process.
DECODE_BUDGET = DecodeBudget(DECODE_BUDGET_BYTES)


def decode_upload(name: str, data: bytes) -> np.ndarray:
    """An uploaded map (PNG or EXR bytes, texture space) as float32 (TEXTURE_TEXELS, TEXTURE_TEXELS, C)
    in [0, 1] (the normal map: unit normals); refused with a 4xx FieldError (an unknown map, too
    large) or RequestError (not a readable image) otherwise."""
    if name not in MAP_NAMES:
        raise with_status(UploadRequest.field_error("map", name, "one of " + ", ".join(MAP_NAMES)), 404)
    if len(data) > MAX_UPLOAD_BYTES:
        raise too_large(f"{name} upload", f"{len(data)} bytes", f"at most {MAX_UPLOAD_BYTES} bytes")
    if data.startswith(PNG_MAGIC):
        decode = _decode_png
    elif data.startswith(EXR_MAGIC):
        decode = _decode_exr
    else:
        raise RequestError(f"{name} upload: not a PNG or EXR file (its first bytes are {data[:8]!r})", 415)
    pixels = decode(name, data)
    pixels = np.clip(np.nan_to_num(pixels, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0).astype(np.float32)
    if name == "roughness":
        return pixels[..., :1]
    rgb = pixels[..., :3] if pixels.shape[2] >= 3 else np.repeat(pixels[..., :1], 3, axis=2)
    if name == "normal":
        return decode_normal_map(rgb)[0].astype(np.float32)
    return rgb


def too_large(where: str, size: str, allowed: str) -> FieldError:
    """An upload (or a body) of ``size`` refused (413): ``<where>: <size> is not allowed; <allowed>``."""
    return with_status(FieldError(where, size, allowed, what=f"{size} is not allowed"), 413)


def _check_pixels(name: str, width: int, height: int) -> None:
    if width < 1 or height < 1 or width * height > MAX_UPLOAD_PIXELS:
        raise too_large(f"{name} upload", f"{width}x{height} pixels", f"at most {MAX_UPLOAD_PIXELS} pixels")


def _resample(channels: list[np.ndarray], scale: float = 1.0) -> np.ndarray:
    """Three (h, w) channels of any numeric type -> (TEXTURE_TEXELS, TEXTURE_TEXELS, 3) float32
    times ``scale``, bilinear (Pillow); one channel at a time is float32 at full size."""
    from PIL import Image

    channels = (channels * 3)[:3] if len(channels) < 3 else channels[:3]  # grey: repeated
    out = np.empty((TEXTURE_TEXELS, TEXTURE_TEXELS, 3), np.float32)
    for c, channel in enumerate(channels):
        full = Image.fromarray(np.ascontiguousarray(channel, np.float32), mode="F")
        out[..., c] = np.asarray(full.resize((TEXTURE_TEXELS, TEXTURE_TEXELS), Image.BILINEAR), np.float32)
        del full
    return out * np.float32(scale)


def _decode_png(name: str, data: bytes) -> np.ndarray:
    """A PNG upload through the project's one bounded image reader (:mod:`materials.imagefile`):
    its size from the IHDR chunk is refused here first (413, our bound), then the reader checks
    it again from Pillow's header before any pixel is decoded."""
    if data[12:16] != b"IHDR":
        raise RequestError(f"{name} upload: not a readable PNG (no IHDR chunk first)", 415)
    width, height = _png_header_size(data)
    _check_pixels(name, width, height)
    side = int(math.isqrt(MAX_UPLOAD_PIXELS))
    with DECODE_BUDGET.reserve(width * height * DECODE_BYTES_PER_PIXEL, f"{name} upload"):
        try:
            pixels, full_scale = read_image(data, f"{name} upload", side, side)
        except MaterialError as exc:
            raise RequestError(f"{name} upload: not a readable PNG ({exc})", 415) from None
        if pixels.ndim == 2:
            pixels = pixels[..., None]
        grey = pixels.shape[-1] < 3  # grey, or grey and alpha
        return _resample([pixels[..., c] for c in ((0,) if grey else (0, 1, 2))], 1.0 / full_scale)


def _png_header_size(data: bytes) -> tuple[int, int]:
    """Width and height from a PNG's IHDR chunk (the first, at a fixed offset)."""
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def _decode_exr(name: str, data: bytes) -> np.ndarray:
    """An EXR upload through the project's one EXR reader: its header is parsed and bounded
    (:func:`pipeline.store.exrheader.check_header`) before OpenEXR sees the file."""
    label = f"{name} upload"
    try:
        header = check_header(data, label, UPLOAD_EXR_BOUNDS)
    except ExrRefused as exc:  # too large for the bounds (413), or not an EXR we read (415)
        too_large = "data window" in exc.reason or "decoded" in exc.reason
        raise RequestError(
            f"{label}: {exc.reason}" if too_large else f"{label}: not a readable EXR ({exc.reason})",
            413 if too_large else 415,
        ) from None
    _check_pixels(name, header.width, header.height)
    with DECODE_BUDGET.reserve(header.width * header.height * DECODE_BYTES_PER_PIXEL, label):
        try:
            layers = read_exr(data, label, UPLOAD_EXR_BOUNDS).layers
        except ShaderballError as exc:
            raise RequestError(f"{label}: not a readable EXR ({exc})", 415) from None
        channels = [layer[..., c] for _, layer in sorted(layers.items()) for c in range(layer.shape[-1])]
        del layers
        return _resample(channels[:1] if len(channels) < 3 else channels[:3])


def maps_from_uploads(uploads: dict[str, np.ndarray]) -> MaterialMaps:
    """The uploaded maps; a map not uploaded is the uniform default (grey, 0.04, 0.3, flat)."""
    shape = (TEXTURE_TEXELS, TEXTURE_TEXELS)
    defaults = UniformMaterial((0.5, 0.5, 0.5), (0.04, 0.04, 0.04), 0.3).to_maps(shape)
    return MaterialMaps(
        diffuse=uploads.get("diffuse", defaults.diffuse),
        specular=uploads.get("specular", defaults.specular),
        roughness=uploads["roughness"][..., 0] if "roughness" in uploads else defaults.roughness,
        normal=uploads.get("normal", defaults.normal),
    )


#: What `serve`'s dataset may be.
DATASET_ALLOWED = "a dataset folder written by `shaderball build`, or its publication"


class NotADataset(ShaderballError):
    """The dataset to serve cannot be: ``what`` says why (the server refuses its ``dataset``
    field with it)."""

    def __init__(self, what: str):
        super().__init__(f"{what}; {DATASET_ALLOWED}")
        self.what = what


class DatasetSamples:
    """The samples of a dataset folder: listed from its manifest, made again from its spec.

    Only ids in the manifest are served; a sample's material comes from the spec snapshot and
    the plan (pipeline.dataset), so no file named by a request is ever opened.
    """

    def __init__(self, root: str):
        # A publication (PUB) carries the folder's spec, description and manifest byte for byte.
        published = os.path.isfile(os.path.join(root, INDEX_FILE))
        layout = Layout(os.path.join(root, DATASET_DIR) if published else root)
        if not os.path.isdir(root) or not os.path.isfile(layout.spec):
            raise NotADataset(f"{format_value(root)} is no dataset folder (it holds no {SPEC_FILE})")
        try:
            self.spec = parse_spec(layout.spec)
            description = json.loads(read_bytes(layout.description, 1 << 20))
            renders = (description.get("counts") or {}).get("renders")
            if not isinstance(renders, int) or not 0 < renders <= MAX_PICKER_SAMPLES:
                raise ValueError(
                    f"its dataset.json counts {renders!r} renders; the picker takes 1 to {MAX_PICKER_SAMPLES}"
                )
            lines = read_manifest(layout, renders).split(b"\n")
            self.samples = dict(_picker_row(json.loads(line), self.spec) for line in lines if line.strip())
            #: The spec's mesh files and maps by SHA-256, as the build recorded them (path -> hex).
            self.sources = description.get("sources") if isinstance(description.get("sources"), dict) else {}
        except (OSError, ValueError, KeyError, TypeError, *USER_ERRORS) as exc:
            raise NotADataset(
                f"{format_value(root)} cannot be read ({exc}); check it with `shaderball validate` or `shaderball verify`"
            ) from None
        self.plan = plan_dataset(self.spec, list_imported_maps(self.spec))
        self.root = root

    def listing(self) -> list[dict]:
        return [{"id": sample_id, **row} for sample_id, (_, row) in self.samples.items()]

    def maps(self, choice: DatasetChoice) -> MaterialMaps:
        entry = self.samples.get(choice.sample)
        if entry is None:
            raise with_status(
                DatasetChoice.field_error("sample", choice.sample, "a sample id listed by /api/info"), 404
            )
        index = entry[0]
        shard = self.plan.shard(next(i for i in range(len(self.plan)) if index in self.plan.material_range(i)))
        plan = next(m for m in shard.materials if m.material_index == index)
        return make_material(plan, self.spec)[0]


def _picker_row(record: dict, spec) -> tuple[str, tuple[int, dict]]:
    """(sample id, (material index, what the picker shows)) of a manifest record."""
    sample_id, index = record["id"], record["material_index"]
    if not isinstance(sample_id, str) or not SAMPLE_ID.fullmatch(sample_id):
        raise ValueError(f"a record's id {sample_id!r} is not a sample id")
    if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < spec.dataset.materials:
        raise ValueError(f"record {sample_id}: material_index {index!r} is not in the spec's range")
    material = record.get("material") or {}
    requested = (record.get("lighting") or {}).get("requested") or {}
    row = {key: requested.get(key) for key in ("elevation_deg", "azimuth_deg", "turbidity")}
    if "environment" in requested:  # an environment-lit sample: its map (base name), turn and scale
        row = {key: requested.get(key) for key in ("environment", "rotation_deg", "intensity")}
    row["object"] = os.path.basename(str((record.get("object") or {}).get("name") or "shaderball"))
    return sample_id, (index, {"kind": material.get("kind"), "family": material.get("family"), **row})


def material_maps(choice, dataset: DatasetSamples | None, uploads: dict[str, np.ndarray]) -> MaterialMaps:
    """The texture-space maps of a view's material."""
    if isinstance(choice, UniformChoice):
        return uniform_maps(choice)
    if isinstance(choice, SvbrdfChoice):
        return svbrdf_maps(choice)
    if isinstance(choice, DatasetChoice):
        if dataset is None:
            raise RequestError("material.kind: 'dataset' needs the server started with --dataset DIR", 400)
        return dataset.maps(choice)
    if isinstance(choice, MapsChoice):
        return maps_from_uploads(uploads)
    raise RequestError(f"material: {choice!r} is not a material", 400)
