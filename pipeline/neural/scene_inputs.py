"""What the network sees of a sample's scene beyond the paper's inputs: the geometry buffers
(``train --geometry``) and a learned code of the environment map (``--environment-code``);
and what each sample's record says of its scene (object, map, rotation), for the splits by
object and by rotation (pipeline.neural.splits) and evaluate's groups.

**Geometry channels** (4, after the 12 maps): the stored ``geometry_normal`` (world space,
unit) encoded as the normal map is, ``(n + 1) / 2``, and ``depth`` (z-depth in metres)
standardised per image over the object's pixels, ``(d - mean) / std`` clipped to +-3 and mapped
to [0, 1] by ``0.5 + z / 6``; both 0 off the object, like the maps. Standardising per image
keeps the object's shape (which parts are nearer) and drops its distance, which the camera rule
(geometry.objects.object_camera) sets per object and the network cannot use across objects.
At a network resolution below the dataset's they are box-averaged as the maps are.

**Environment codes**: each map digest the training split holds gets a row of a learned
embedding (pipeline.neural.network); its order (sorted digests) is recorded in config.json's
``network.environments``, so evaluate and infer give a sample the row its map had in training;
a sample under the sun or under a map the run never saw gets row 0.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import torch
from torch.utils.data import Dataset

from materials import encode_normal_map
from pipeline.neural.config import TrainConfig

GEOMETRY_LAYERS = ("geometry_normal", "depth")
#: Input channels the geometry adds: the normal's 3 and depth's 1.
GEOMETRY_CHANNELS = 4
#: Depth standardised per image is clipped to this many standard deviations.
DEPTH_CLIP = 3.0
#: How config.json names the geometry channels' encoding (evaluate and infer read it).
GEOMETRY_ENCODING = "geometry_normal (n+1)/2; depth standardised over the mask, clip 3, 0.5+z/6; 0 off the object"
#: Materials whose geometry channels a process keeps.
CACHE_MATERIALS = 64
SUN = "sun_sky"


def geometry_channels(layers: dict[str, np.ndarray], factor: int = 1) -> np.ndarray:
    """A maps file's ``geometry_normal``, ``depth`` and ``mask`` layers -> (4, R, R) float32
    (the module's docstring); ``factor``: box-averaged over factor x factor pixels."""
    mask = layers["mask"][..., 0] > 0.5
    depth = layers["depth"][..., 0].astype(np.float64)
    chw = np.zeros((GEOMETRY_CHANNELS, *mask.shape), np.float32)
    chw[0:3] = encode_normal_map(layers["geometry_normal"]).transpose(2, 0, 1) * mask
    if mask.any():
        inside = depth[mask]
        z = (depth - inside.mean()) / max(float(inside.std()), 1e-6)
        chw[3] = np.where(mask, 0.5 + np.clip(z, -DEPTH_CLIP, DEPTH_CLIP) / (2 * DEPTH_CLIP), 0.0)
    if factor > 1:
        c, h, w = chw.shape
        chw = chw.reshape(c, h // factor, factor, w // factor, factor).mean(axis=(2, 4), dtype=np.float64)
    return chw.astype(np.float32)


def stored_layers(source) -> list[str]:
    """The layers the dataset's maps files hold (its first sample's, decoded: what storage.layers
    wrote, in a folder or a publication alike)."""
    sample = source.samples[0]
    return sorted(source.read_layers(sample.maps, ("mask",), screen=True))


def require_geometry(source) -> None:
    """Refuse ``--geometry`` (the field ``geometry``) on a dataset whose maps hold no geometry
    layers, naming storage.layers and the missing layer."""
    layers = stored_layers(source)
    missing = [name for name in GEOMETRY_LAYERS if name not in layers]
    if missing:
        raise TrainConfig.field_error(
            "geometry",
            True,
            'a dataset built with storage.layers naming "geometry_normal" and "depth", or no {geometry}',
            what=f"the dataset {source.root} stores no {' and no '.join(missing)} layer "
            f"(its storage.layers: {', '.join(layers)})",
        )


@dataclass(frozen=True)
class SampleScene:
    """What a sample's record says of its scene: the object's name, the light's source, the
    map's digest and base name and its rotation (None under the sun)."""

    object: str
    light_source: str
    environment: str | None = None
    environment_file: str | None = None
    rotation_deg: float | None = None

    @classmethod
    def of(cls, record: dict) -> SampleScene:
        name = (record.get("object") or {}).get("name") or "shaderball"
        lighting = record.get("lighting") or {}
        if lighting.get("source") != "environment":
            return cls(str(name), SUN)
        rotation = lighting.get("rotation_deg")
        return cls(
            str(name),
            "environment",
            lighting.get("sha256"),
            lighting.get("file"),
            float(rotation) if isinstance(rotation, (int, float)) else None,
        )


def scenes(source) -> dict[str, SampleScene]:
    """Sample id -> :class:`SampleScene` of every sample of ``source`` (each record parsed once)."""
    found = getattr(source, "_scenes", None)
    if found is None:
        found = {sample.id: SampleScene.of(source.records[sample.id]) for sample in source.samples}
        source._scenes = found  # noqa: SLF001 (kept with the dataset it describes)
    return found


def material_objects(source) -> dict[str, str]:
    """Material id -> its object's name (a material is rendered on one object)."""
    by_id = scenes(source)
    return {sample.material_id: by_id[sample.id].object for sample in source.samples}


@dataclass(frozen=True)
class InputPlan:
    """What the network takes beyond the maps and the lighting vector."""

    geometry: bool = False
    code_size: int = 0
    environments: tuple[str, ...] = ()  # map digests with a code, in the embedding's order (row 1 on)

    @classmethod
    def for_run(cls, config: TrainConfig, source, train_ids) -> InputPlan:
        """A new run's plan: geometry checked stored; codes for the training materials' maps."""
        if config.geometry:
            require_geometry(source)
        if not config.environment_code:
            return cls(config.geometry)
        keep, by_id = set(train_ids), scenes(source)
        digests = sorted(
            {by_id[s.id].environment for s in source.samples if s.material_id in keep and by_id[s.id].environment}
        )
        if not digests:
            raise TrainConfig.field_error(
                "environment_code",
                config.environment_code,
                "0 on a dataset without environment-lit training samples",
                what=f"{config.environment_code}: no training sample is lit by an environment map",
            )
        return cls(config.geometry, config.environment_code, tuple(digests))

    @classmethod
    def of_network(cls, network: dict) -> InputPlan:
        """The plan a run's config.json ``network`` section records (a run before: none)."""
        return cls(
            bool(network.get("extra_channels", 0)),
            int(network.get("environment_code", 0)),
            tuple(network.get("environments") or ()),
        )

    def network_record(self) -> dict:
        """config.json's ``network`` keys for this plan (none for the paper's inputs)."""
        record = {}
        if self.geometry:
            record.update(extra_channels=GEOMETRY_CHANNELS, geometry=GEOMETRY_ENCODING)
        if self.code_size:
            record.update(environment_code=self.code_size, environments=list(self.environments))
        return record

    @property
    def plain(self) -> bool:
        return not self.geometry and not self.code_size

    def environment_index(self, scene: SampleScene) -> int:
        if scene.environment in self.environments:
            return self.environments.index(scene.environment) + 1
        return 0


class NetworkInputs(Dataset):
    """A dataset's samples as the network of ``plan`` takes them: ``maps`` with the geometry
    channels after the 12, ``environment`` the row of
    the sample's map code; other keys as the dataset gives them. ``samples`` and the dataset's
    attributes pass through."""

    def __init__(self, base, plan: InputPlan):
        self.base, self.plan = base, plan
        self._cache: OrderedDict[str, torch.Tensor] = OrderedDict()

    def __getattr__(self, name):
        if name in ("base", "plan", "_cache"):
            raise AttributeError(name)
        return getattr(self.base, name)

    def __len__(self) -> int:
        return len(self.base)

    def geometry(self, sample) -> torch.Tensor:
        cached = self._cache.get(sample.material_id)
        if cached is None:
            layers = self.base.read_layers(sample.maps, (*GEOMETRY_LAYERS, "mask"), screen=True)
            cached = self._cache[sample.material_id] = torch.from_numpy(geometry_channels(layers, self.base.factor))
            while len(self._cache) > CACHE_MATERIALS:
                self._cache.popitem(last=False)
        return cached

    def __getitem__(self, index: int) -> dict:
        item = self.base[index]
        if self.plan.plain:
            return item
        sample = self.base.samples[index]
        if self.plan.geometry:
            item["maps"] = torch.cat([item["maps"], self.geometry(sample)])
        if self.plan.code_size:
            scene = SampleScene.of(self.base.records[sample.id])
            item["environment_code"] = torch.tensor(self.plan.environment_index(scene), dtype=torch.long)
        return item


def with_inputs(dataset, plan: InputPlan):
    """``dataset`` as the network of ``plan`` takes it (itself for the paper's inputs)."""
    return dataset if dataset is None or plan.plain else NetworkInputs(dataset, plan)
