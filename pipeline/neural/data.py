"""A dataset folder as torch samples: the network's 12-channel input, the lighting vector,
the tone-mapped target and the mask, read from the EXR files the manifest lists.

A sample is a plain dict of tensors (``maps`` (12, R, R), ``light`` (4,), ``target``
(3, R, R), ``mask`` (1, R, R)) plus its ``id`` and ``material_id``:

- ``maps``: diffuse RGB, specular RGB, normal-map colour RGB (``(n + 1) / 2``, the
  renderer's encoding, ``materials.encode_normal_map``; 0 off the ball like the other
  maps), roughness repeated 3 times; each in [0, 1].
- ``light``: the record's ``lighting_vector`` as stored (unit sun direction, turbidity);
  the network's encoding of it is :func:`pipeline.neural.network.light_input`.
- ``target``: the render through :func:`pipeline.image.tonemap.tonemap`.
- ``mask``: 1 where a pixel centre sees the material.

At a network resolution R below the dataset's D (D a multiple of R), every image is
box-averaged over D/R x D/R pixels first (renders in linear HDR, before the tone map).

Every file is read as bytes once, only at the size the manifest records for it (a render
grown in place is refused before a byte is read, as validate refuses it:
:class:`pipeline.store.bounded_read.Recorded`), its SHA-256 compared with the manifest's on its
first read in a process (``check_hashes=False`` skips it), then decoded. A material's maps are
assembled once and kept (a bounded cache per process) for all its lightings. Paths that
leave the dataset folder (absolute, ``..``, or through a symbolic link) are refused.

The source is a dataset folder or a publication (the folder `shaderball publish` writes,
recognised by its ``publication.json`` or ``SHA256SUMS``): :func:`open_dataset` opens
either, with the same samples in the same order, the same tensors and the same identity
(so the same split). A publication is checked first, all of it, by
``pipeline.publish.reader`` (every SHA-256, tar header, member and EXR header, streamed;
nothing extracted); then each file is read at the offset where its checked bytes lie in
its tar (:func:`pipeline.publish.reader.read_located`, no ``tarfile``), and its SHA-256
compared again on its first read in a process. A publication that does not verify is a
user error (exit code 2), named with the reader's message.

A dataset that cannot be opened is refused naming the command's dataset (a
:class:`pipeline.fields.FieldError` of the field ``dataset``: :func:`dataset_refused`); a
file of it that cannot be used is refused naming the file (a ShaderballError: it may be
raised in a loader's worker process, whose errors torch rebuilds from their message).

A sample that ``shaderball validate`` refuses is refused here too, when it is read: every
file's EXR header is checked before it is decoded (single-part scanline, a bounded data
window and channel count, the decoded size within the expected image: :func:`pipeline.store.exrheader.check_header`), then its
decoded content by validate's own checks (:func:`pipeline.check.inspect.content_issues`:
the layers and channels the network needs, the manifest's size, float sample types; maps
finite, in range, unit normals; a render finite, and non-negative unless the render policy
flagged it), on its first read in a process. The policy is to stop, never to skip: a ShaderballError (exit code 2) names
the file and what is wrong, and training writes nothing for an epoch it did not finish
(a fresh run reads every sample for its baseline before it writes anything).

Where a sample's files are read is pipeline.neural.file_sources; what opening a dataset
keeps of its manifest, pipeline.neural.manifest_index.

**Scene fields** (opt in: :func:`with_scene`, so a sample of :func:`open_dataset` keeps the keys
above and training its batches): ``object`` (the object's name: ``shaderball``, ``sphere``, a
mesh file's base name, ...; ``shaderball`` where the record names none), ``light_source``
(``sun_sky`` or ``environment``), ``environment`` (the map's base name, ``""`` under the sun),
and, only where the sample's maps file stores them (``storage.layers``; never invented), the
object's geometry as tensors: ``geometry_normal`` (3, R, R), world-space unit normals, and
``depth`` (1, R, R), metres from the camera plane; 0 off the object, box-averaged like the maps.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections import OrderedDict
from collections.abc import Mapping, Sequence

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, get_worker_info

from materials import encode_normal_map
from pipeline.check.inspect import content_issues, sample_expectations
from pipeline.errors import ShaderballError, quoted
from pipeline.fields import FieldError
from pipeline.image.tonemap import DEFAULT_EXPOSURE, tonemap
from pipeline.neural.config import TrainConfig
from pipeline.neural.file_sources import FolderFiles, PublishedFiles, dataset_refused, refused
from pipeline.neural.manifest_index import (
    ManifestIndex,
    SampleColumns,
    SampleFiles,
    byte_lines,
    checked_record,
    expected_renders,
    folder_manifest,
    index_records,
)
from pipeline.neural.network import check_network_resolution
from pipeline.neural.scene_inputs import SampleScene
from pipeline.publish.names import INDEX_FILE, SUMS_FILE
from pipeline.publish.reader import open_publication
from pipeline.publish.refusal import Refused
from pipeline.store.bounded_read import file_digest, iter_lines, list_bound
from pipeline.store.exr import ROLE_LAYERS, layer_bounds, read_exr
from pipeline.store.exrheader import ExrBounds, ExrRefused, check_header
from pipeline.store.layout import DESCRIPTION_FILE, MANIFEST_FILE, SPEC_FILE

MAP_LAYERS = ("diffuse", "specular", "roughness", "normal", "mask")
#: Materials whose assembled maps a process keeps (400x400: 7.7 MB each).
DEFAULT_CACHE_MATERIALS = 64


def box_downsample(image: np.ndarray, factor: int) -> np.ndarray:
    """(H, W, C) -> (H/f, W/f, C), the mean of each f x f block."""
    if factor == 1:
        return image
    h, w, c = image.shape
    return (
        image.reshape(h // factor, factor, w // factor, factor, c)
        .mean(axis=(1, 3), dtype=np.float64)
        .astype(np.float32)
    )


def assemble_maps(layers: dict[str, np.ndarray], factor: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """A maps file's layers -> (12, R, R) network input and (1, R, R) mask, float32."""
    mask = layers["mask"][..., 0].astype(np.float32)
    h, w = mask.shape
    chw = np.empty((13, h, w), np.float32)
    chw[0:3] = layers["diffuse"].transpose(2, 0, 1)
    chw[3:6] = layers["specular"].transpose(2, 0, 1)
    chw[6:9] = encode_normal_map(layers["normal"]).transpose(2, 0, 1) * (mask > 0.5)
    chw[9:12] = layers["roughness"][..., 0]
    chw[12] = mask
    if factor > 1:
        chw = (
            chw.reshape(13, h // factor, factor, w // factor, factor)
            .mean(axis=(2, 4), dtype=np.float64)
            .astype(np.float32)
        )
    return chw[:12], chw[12:]


def collate_samples(samples: list[dict]) -> dict:
    """Samples -> one batch dict: each tensor field stacked along a new first axis, each
    other field (``id``, ``material_id``) a list; the same values as torch's default collation.

    numpy stacks into a preallocated tensor (in shared memory inside a worker, as the default
    does, so the batch crosses to the main process without a copy). torch's default stacks with
    ``torch.stack``, whose intra-op threads spin against any other busy process on a small
    machine: the loader was measured falling from 643 to 42 samples/s, 318 of 473 ms in the stack.
    numpy's copy runs on the calling thread alone."""
    batch = {}
    for key, first in samples[0].items():
        if not isinstance(first, torch.Tensor):
            batch[key] = [sample[key] for sample in samples]
            continue
        out = torch.empty((len(samples), *first.shape), dtype=first.dtype)
        if get_worker_info() is not None:
            out.share_memory_()
        np.stack([sample[key].numpy() for sample in samples], out=out.numpy())
        batch[key] = out
    return batch


class Batches(DataLoader):
    """A DataLoader whose worker processes' user errors reach the caller as the error they
    raised, with its own message: torch re-raises an exception of a worker as one of the same
    type whose message holds the worker's traceback, which the CLI would print."""

    def __iter__(self):
        iterator = super().__iter__()
        while True:
            try:
                batch = next(iterator)
            except StopIteration:
                return
            except ShaderballError as exc:
                raise type(exc)(worker_message(exc)) from None
            yield batch


def worker_message(exc: Exception) -> str:
    """The message a worker's exception was raised with (torch's wrapper text taken off)."""
    text = str(exc)
    marker = f"{type(exc).__module__}.{type(exc).__qualname__}: "
    if text.startswith("Caught ") and marker in text:
        return text.rsplit(marker, 1)[1].strip()
    return text


def batches(dataset, batch_size: int, workers: int = 0, **options) -> DataLoader:
    """A DataLoader over ``dataset`` that collates with :func:`collate_samples` (:class:`Batches`)."""
    return Batches(dataset, batch_size=batch_size, num_workers=workers, collate_fn=collate_samples, **options)


def decode_exr(data: bytes, label: str, bounds: ExrBounds) -> dict[str, np.ndarray]:
    """The layers of an EXR file's bytes, its header checked against ``bounds`` before
    anything decodes it (:func:`pipeline.store.exrheader.check_header`)."""
    try:
        check_header(data, label, bounds)
    except ExrRefused as exc:
        raise ShaderballError(str(exc)) from None
    return read_exr(data, label, bounds).layers


class ShaderballDataset(Dataset):
    """Samples of a dataset folder or a publication (see the module's docstring); build with
    :func:`open_dataset`. ``files`` reads them (default: the folder ``root``); ``records``
    maps each sample id to its manifest record."""

    def __init__(
        self,
        root: str,
        samples: Sequence[SampleFiles],
        resolution: int,
        factor: int,
        exposure: float = DEFAULT_EXPOSURE,
        check_hashes: bool = True,
        cache_materials: int = DEFAULT_CACHE_MATERIALS,
        identity: dict | None = None,
        files=None,
        records: Mapping[str, dict] | None = None,
    ):
        self.root = root
        self.samples = samples
        self.resolution = resolution
        self.factor = factor
        self.exposure = exposure
        self.check_hashes = check_hashes
        self.cache_materials = cache_materials
        self.identity = identity or {}
        #: What the dataset holds, whatever folder holds it (pipeline.neural.evaluate.same_dataset); {}: unknown.
        self.content: dict = {}
        self.files = files if files is not None else FolderFiles(root)
        self.records = records or {}
        self.material_ids = (
            samples.material_ids() if isinstance(samples, SampleColumns) else sorted({s.material_id for s in samples})
        )
        self._verified: set[str] = set()
        self._content_checked: set[str] = set()  # files whose content passed, in this process
        self._maps_cache: OrderedDict[str, tuple[torch.Tensor, torch.Tensor]] = OrderedDict()
        self.maps_reads = 0  # maps files decoded by this process (tests count them)

    def __len__(self) -> int:
        return len(self.samples)

    def subset(self, material_ids) -> ShaderballDataset:
        keep = set(material_ids)
        view = ShaderballDataset(
            self.root,
            self.samples.of_materials(keep)
            if isinstance(self.samples, SampleColumns)
            else [s for s in self.samples if s.material_id in keep],
            self.resolution,
            self.factor,
            self.exposure,
            self.check_hashes,
            self.cache_materials,
            self.identity,
            self.files,
            self.records,
        )
        view.content = self.content
        return view

    def read_layers(
        self, ref: tuple[str, str], layers: tuple[str, ...], screen: bool = False, flagged: bool = False
    ) -> dict[str, np.ndarray]:
        """The decoded layers of the file ``ref`` (key, sha256, bytes), which must hold
        ``layers``; ``screen``: and be the dataset's resolution (renders, maps); ``flagged``: a
        render the render policy flagged (bad pixels recorded), whose negative values are allowed."""
        key, sha256, size = ref
        data = self.files.read(key, size)
        if self.check_hashes and key not in self._verified:
            if hashlib.sha256(data).hexdigest() != sha256:
                raise self.files.changed(key)
            self._verified.add(key)
        label = self.files.label(key)
        role = "render" if "render" in layers else "maps" if screen else "texture"
        side = self.resolution * self.factor if screen else None
        decoded = decode_exr(data, label, layer_bounds(side, ROLE_LAYERS[role], exact=screen))
        absent = [name for name in layers if name not in decoded]
        if absent:
            raise ShaderballError(
                f"{label}: no {', '.join(absent)} layer (the network needs "
                f"{', '.join(layers)}; build with storage.layers naming them)"
            )
        shape = decoded[layers[0]].shape[:2]
        if screen and shape != (self.resolution * self.factor,) * 2:
            raise ShaderballError(
                f"{label}: {shape[0]}x{shape[1]} pixels, the manifest says {self.resolution * self.factor}"
            )
        if key not in self._content_checked:
            role = ("render" if "render" in layers else "maps") if screen else "texture"
            self.refuse_bad_content(label, decoded, role, flagged)
            self._content_checked.add(key)
        return decoded

    def refuse_bad_content(self, label: str, layers: dict[str, np.ndarray], role: str, flagged: bool) -> None:
        """A ShaderballError naming the file and the first of its issues that validate reports."""
        expect = sample_expectations(self.resolution * self.factor)[role]
        issues = content_issues(layers, expect, flagged)
        if issues:
            kind, text = issues[0]
            more = f" (and {len(issues) - 1} more)" if len(issues) > 1 else ""
            raise ShaderballError(
                f"{label}: {text}{more} [{kind}]: a sample validate refuses; nothing trains "
                f"on it (check the {self.files.kind} with {self.files.checker}, then repair or rebuild it)"
            )

    def _read(self, ref: tuple[str, str, int], layers: tuple[str, ...], flagged: bool = False) -> dict[str, np.ndarray]:
        return self.read_layers(ref, layers, screen=True, flagged=flagged)

    def flagged(self, sample: SampleFiles) -> bool:
        """Whether the render policy flagged the sample's render (its record, parsed when asked)."""
        record = self.records.get(sample.id) or {}
        return bool((record.get("stats") or {}).get("flagged"))

    def material_maps(self, sample: SampleFiles) -> tuple[torch.Tensor, torch.Tensor]:
        cached = self._maps_cache.get(sample.material_id)
        if cached is not None:
            self._maps_cache.move_to_end(sample.material_id)
            return cached
        layers = self._read(sample.maps, MAP_LAYERS)
        maps, mask = assemble_maps(layers, self.factor)
        self.maps_reads += 1
        entry = (torch.from_numpy(maps), torch.from_numpy(mask))
        self._maps_cache[sample.material_id] = entry
        while len(self._maps_cache) > self.cache_materials:
            self._maps_cache.popitem(last=False)
        return entry

    def target(self, sample: SampleFiles) -> torch.Tensor:
        render = self._read(sample.render, ("render",), self.flagged(sample))["render"].astype(np.float32)
        render = box_downsample(render, self.factor)
        return torch.from_numpy(np.ascontiguousarray(tonemap(render, self.exposure).transpose(2, 0, 1)))

    def __getitem__(self, index: int) -> dict:
        sample = self.samples[index]
        maps, mask = self.material_maps(sample)
        return {
            "maps": maps,
            "light": torch.tensor(sample.lighting_vector, dtype=torch.float32),
            "target": self.target(sample),
            "mask": mask,
            "id": sample.id,
            "material_id": sample.material_id,
        }


#: The scene fields of a sample of :func:`with_scene` (strings), and its geometry layers (key ->
#: channels), present only where the dataset stores them.
SCENE_KEYS = ("object", "light_source", "environment")
GEOMETRY_KEYS = {"geometry_normal": 3, "depth": 1}


def scene_fields(record: dict) -> dict[str, str]:
    """A record's ``object``, ``light_source`` and ``environment`` (see the module's docstring), as
    :class:`pipeline.neural.scene_inputs.SampleScene` reads them: the shaderball's and the sun's
    records name neither, and are as they were before objects."""
    scene = SampleScene.of(record)
    return {"object": scene.object, "light_source": scene.light_source, "environment": scene.environment_file or ""}


def geometry_tensors(layers: dict[str, np.ndarray], factor: int = 1) -> dict[str, torch.Tensor]:
    """The geometry layers a maps file holds (of :data:`GEOMETRY_KEYS`), each (C, R, R) float32,
    box-averaged over ``factor`` x ``factor`` pixels; a layer the file lacks is left out."""
    out = {}
    for name, channels in GEOMETRY_KEYS.items():
        if name in layers:
            image = layers[name].reshape(*layers[name].shape[:2], channels).astype(np.float32)
            out[name] = torch.from_numpy(np.ascontiguousarray(box_downsample(image, factor).transpose(2, 0, 1)))
    return out


class SceneSamples(Dataset):
    """A dataset's samples with their scene fields and stored geometry layers (the module's
    docstring); build with :func:`with_scene`. ``subset`` and the dataset's attributes pass
    through; a material's geometry is decoded once and kept (a bounded cache per process)."""

    def __init__(self, base: ShaderballDataset):
        self.base = base
        self._geometry: OrderedDict[str, dict[str, torch.Tensor]] = OrderedDict()

    def __getattr__(self, name):
        if name.startswith("__") or name in ("base", "_geometry"):
            raise AttributeError(name)
        return getattr(self.base, name)

    def __len__(self) -> int:
        return len(self.base)

    def subset(self, material_ids) -> SceneSamples:
        return SceneSamples(self.base.subset(material_ids))

    def geometry(self, sample: SampleFiles) -> dict[str, torch.Tensor]:
        """The stored geometry layers of the sample's maps file (none where it holds none)."""
        cached = self._geometry.get(sample.material_id)
        if cached is None:
            layers = self.base.read_layers(sample.maps, ("mask",), screen=True)
            cached = self._geometry[sample.material_id] = geometry_tensors(layers, self.base.factor)
            while len(self._geometry) > self.base.cache_materials:
                self._geometry.popitem(last=False)
        else:
            self._geometry.move_to_end(sample.material_id)
        return cached

    def __getitem__(self, index: int) -> dict:
        item = self.base[index]
        sample = self.base.samples[index]
        return {**item, **scene_fields(self.base.records[sample.id]), **self.geometry(sample)}


def with_scene(dataset: ShaderballDataset) -> SceneSamples:
    """``dataset``'s samples with ``object``, ``light_source``, ``environment`` and the stored
    geometry layers (see the module's docstring)."""
    return SceneSamples(dataset)


def one_resolution(sizes: set, root: str) -> int:
    if len(sizes) != 1 or not isinstance(next(iter(sizes)), int):
        raise dataset_refused(
            root,
            f"{quoted(root)} has renders of several or unknown resolutions {sorted(map(str, sizes))}",
            "a dataset of one render resolution; check it with `shaderball validate`",
        )
    return next(iter(sizes))


class ResolutionMismatch(FieldError):
    """A network resolution (the field ``resolution``) that does not divide the dataset's;
    callers that did not take it from the user (``evaluate``: the run's) say what the user
    can do instead."""

    def __init__(self, native: int, requested: int | None):
        super().__init__(
            TrainConfig.field_label("resolution"),
            requested,
            f"a multiple of 16 that divides the dataset's resolution {native}"
            + ("" if requested is not None else f" (the network needs a multiple of 16; {native} is not)"),
            name="resolution",
            owner=TrainConfig,
        )
        self.native, self.requested = native, requested


def network_resolution(native: int, requested: int | None) -> tuple[int, int]:
    """(network resolution, box factor) for a dataset of ``native`` pixels; ``requested`` is
    a network resolution (:class:`pipeline.neural.config.NetworkResolution`) or None (the
    dataset's)."""
    if requested is None:
        if native % 16:
            raise ResolutionMismatch(native, None)
        return native, 1
    check_network_resolution(requested)
    if native % requested:
        raise ResolutionMismatch(native, requested)
    return requested, native // requested


def is_publication(root: str) -> bool:
    """Whether ``root`` is a publication (it holds ``publication.json`` or ``SHA256SUMS``)
    rather than a dataset folder (``dataset.json``, ``manifest.jsonl``); both is refused."""
    if not os.path.isdir(root):
        return False
    published = [n for n in (INDEX_FILE, SUMS_FILE) if os.path.lexists(os.path.join(root, n))]
    folder = [n for n in (DESCRIPTION_FILE, MANIFEST_FILE) if os.path.lexists(os.path.join(root, n))]
    if published and folder:
        raise dataset_refused(
            root,
            f"{quoted(root)} holds both a dataset folder's {folder[0]} and a publication's {published[0]}; it is neither",
            "name a folder `shaderball build` or `shaderball publish` wrote",
        )
    return bool(published)


def open_dataset(
    root: str,
    resolution: int | None = None,
    exposure: float = DEFAULT_EXPOSURE,
    check_hashes: bool = True,
    cache_materials: int = DEFAULT_CACHE_MATERIALS,
) -> ShaderballDataset:
    """A complete dataset folder, or a publication of one, as a :class:`ShaderballDataset`
    (all samples, in manifest order; see the module's docstring)."""
    if is_publication(root):
        return open_published(root, resolution, exposure, check_hashes, cache_materials)
    description, path = folder_manifest(root)
    bound = list_bound(expected_renders(description))
    files = FolderFiles(root)
    try:
        index = index_records(iter_lines(path, bound), path, files, description, root, path, "`shaderball validate`")
        manifest_sha256 = file_digest(path, bound)[1]
    except OSError as exc:
        raise ShaderballError(
            f"{path} cannot be read ({exc.strerror}); check the folder with `shaderball validate`"
        ) from None
    return _make(root, description, index, manifest_sha256, files, resolution, exposure, check_hashes, cache_materials)


def open_published(
    root: str, resolution: int | None, exposure: float, check_hashes: bool, cache_materials: int
) -> ShaderballDataset:
    """A publication as a :class:`ShaderballDataset`, for :func:`open_dataset` (which holds the
    defaults): checked whole first (every tar streamed through the reader), then read member by
    member at the checked offsets."""
    try:
        publication = open_publication(root)
        located = publication.locate()
    except Refused as exc:
        raise refused(root, exc) from None
    description = json.loads(publication.source_files[DESCRIPTION_FILE])
    if not isinstance(description, dict):
        raise dataset_refused(
            root,
            f"{quoted(root)}: its dataset/{DESCRIPTION_FILE} is not a JSON object",
            "check it with `shaderball verify`",
        )
    manifest = publication.source_files[MANIFEST_FILE]
    where = os.path.join(root, "dataset", MANIFEST_FILE)
    keep = set()
    for number, _offset, line in byte_lines(manifest):
        keep.update(entry["path"] for entry in checked_record(line, number, where, "`shaderball verify`")["files"])
    files = PublishedFiles(root, {path: at for path, at in located.items() if path in keep})
    del keep
    index = index_records(byte_lines(manifest), manifest, files, description, root, where, "`shaderball verify`")
    manifest_sha256 = hashlib.sha256(manifest).hexdigest()
    dataset = _make(
        root, description, index, manifest_sha256, files, resolution, exposure, check_hashes, cache_materials
    )
    dataset.spec_bytes = publication.source_files.get(SPEC_FILE)  # verified with the rest
    return dataset


def _make(
    root: str,
    description: dict,
    index: ManifestIndex,
    manifest_sha256: str,
    files,
    resolution,
    exposure,
    check_hashes,
    cache_materials,
) -> ShaderballDataset:
    native = one_resolution(index.resolutions, root)
    net_res, factor = network_resolution(native, resolution)
    identity = {
        "spec_digest": description.get("spec_digest"),
        "manifest_sha256": manifest_sha256,
        "name": description.get("name"),
        "resolution": native,
        "variant": description.get("variant"),
    }
    dataset = ShaderballDataset(
        root,
        index.samples,
        net_res,
        factor,
        exposure,
        check_hashes,
        cache_materials,
        identity,
        files=files,
        records=index.records,
    )
    dataset.content = {"spec_digest": description.get("spec_digest"), "samples_sha256": index.samples_sha256}
    #: A publication's spec.toml (None for a folder: its snapshot is read where it is needed).
    dataset.spec_bytes = None
    return dataset
