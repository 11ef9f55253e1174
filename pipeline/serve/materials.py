"""A view's material as texture-space maps: uniform values, a procedural SVBRDF, a dataset
sample (made again from the dataset's spec and plan), or maps the page uploaded or painted.

Uploads are bounded before they are decoded: the body's bytes by the server, then the
image's pixel count from its header (Pillow's lazy open, OpenEXR's header-only read), and
only then the pixels. A dataset sample is picked by its id, which must be in the dataset's
manifest; the id never becomes a path.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from materials import MaterialMaps, UniformMaterial, decode_normal_map, sample_svbrdf
from materials.errors import MaterialError
from materials.imagefile import read_image
from pipeline.dataset.materialize import make_material
from pipeline.dataset.plan import list_imported_maps, plan_dataset, seeded_rng
from pipeline.dataset.spec import parse_spec
from pipeline.errors import USER_ERRORS, ShaderballError
from pipeline.fields import FieldError, format_value
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
from pipeline.store.exr import read_exr
from pipeline.store.exrheader import ExrBounds, ExrRefused, check_header
from pipeline.store.folder import read_bytes, read_manifest
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


def decode_upload(name: str, data: bytes) -> np.ndarray:
    """An uploaded map (PNG or EXR bytes, texture space) as float32 (TEXTURE_TEXELS, TEXTURE_TEXELS, C)
    in [0, 1] (the normal map: unit normals); refused with a 4xx FieldError (an unknown map, too
    large) or RequestError (not a readable image) otherwise."""
    if name not in MAP_NAMES:
        raise with_status(UploadRequest.field_error("map", name, "one of " + ", ".join(MAP_NAMES)), 404)
    if len(data) > MAX_UPLOAD_BYTES:
        raise too_large(f"{name} upload", f"{len(data)} bytes", f"at most {MAX_UPLOAD_BYTES} bytes")
    if data.startswith(PNG_MAGIC):
        pixels = _decode_png(name, data)
    elif data.startswith(EXR_MAGIC):
        pixels = _decode_exr(name, data)
    else:
        raise RequestError(f"{name} upload: not a PNG or EXR file (its first bytes are {data[:8]!r})", 415)
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


def _resample(array: np.ndarray) -> np.ndarray:
    """(h, w, C) float32 -> (TEXTURE_TEXELS, TEXTURE_TEXELS, C), bilinear (Pillow, per channel)."""
    from PIL import Image

    channels = [
        np.asarray(
            Image.fromarray(np.ascontiguousarray(array[..., c], np.float32), mode="F").resize(
                (TEXTURE_TEXELS, TEXTURE_TEXELS), Image.BILINEAR
            ),
            np.float32,
        )
        for c in range(array.shape[2])
    ]
    return np.stack(channels, axis=-1)


def _decode_png(name: str, data: bytes) -> np.ndarray:
    """A PNG upload through the project's one bounded image reader (:mod:`materials.imagefile`):
    its size from the IHDR chunk is refused here first (413, our bound), then the reader checks
    it again from Pillow's header before any pixel is decoded."""
    if data[12:16] == b"IHDR":
        _check_pixels(name, *_png_header_size(data))
    side = int(math.isqrt(MAX_UPLOAD_PIXELS))
    try:
        pixels, full_scale = read_image(data, f"{name} upload", side, side)
    except MaterialError as exc:
        raise RequestError(f"{name} upload: not a readable PNG ({exc})", 415) from None
    array = pixels.astype(np.float32) / np.float32(full_scale)
    if array.ndim == 2:
        array = array[..., None]
    if array.shape[-1] < 3:  # grey, or grey and alpha
        array = np.repeat(array[..., :1], 3, axis=-1)
    return _resample(array[..., :3])


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
    try:
        layers = read_exr(data, label, UPLOAD_EXR_BOUNDS).layers
    except ShaderballError as exc:
        raise RequestError(f"{label}: not a readable EXR ({exc})", 415) from None
    array = np.concatenate([np.asarray(v, np.float32) for _, v in sorted(layers.items())], axis=-1)
    if array.shape[-1] < 3:
        array = np.repeat(array[..., :1], 3, axis=-1)
    return _resample(array[..., :3])


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
