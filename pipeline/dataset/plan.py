"""The build plan: every shard, material and render of a dataset, with their seeds.

:func:`plan_dataset` is a pure, deterministic function of the spec (and, for imported
SVBRDF folders, of the sorted names of their map files). Nothing in it depends on
worker count, scheduling, order of execution, time or host; ``shard_size`` changes only
how materials are grouped into shards, never a seed, a lighting or a material's kind.

Seed derivation (also in docs/spec.md). Each stream has a 64-bit key,
``key(S) = SeedSequence(entropy=dataset.seed, spawn_key=(S,)).generate_state(1, uint64)[0]``,
with a distinct tag S per stream. A seed for index i of stream S is then
``mix64(key(S) + i mod 2^64) >> 1``, ``mix64`` being SplitMix64's bijective finaliser:
distinct indices give distinct 64-bit words, and the shift keeps seeds in 63 bits so they
fit TOML and JSON integers. (One SeedSequence per material and stream would cost ~1 s for
the paper spec; this costs milliseconds and makes distinct indices provably distinct.)

- ``material_seed`` of material m: index m of STREAM_MATERIAL. Keyed by m only: a
  material's maps are the same under all its lightings, and do not change with
  lights_per_material, svbrdf_fraction, shard_size or anything but dataset.seed.
- ``light_seed`` of material m: index m of STREAM_LIGHTS. All lightings of a material
  are drawn *jointly*, ``sky.sample_lights(seeded_rng(light_seed), L, ranges)`` with
  L = lights_per_material, so stratified and Sobol' schemes stratify across a
  material's lightings; light l is element l of that draw.
- ``render_seed`` of (m, l), for ``mi.render(..., seed=...)`` (32 bits):
  ``mix32(key32 + m * 1000 + l mod 2^32)``, key32 the low 32 bits of key(STREAM_RENDER),
  ``mix32`` a bijective 32-bit hash: all render seeds of a dataset are distinct.
- which materials are SVBRDF: the first k = floor(svbrdf_fraction * materials + 0.5)
  entries of ``seeded_rng(index 0 of STREAM_SVBRDF).permutation(materials)``; the j-th
  of them (in permutation order) gets source j mod S of the list
  ``svbrdf_families + svbrdf_folders`` (S entries), so sources are balanced to within one.
- which file of imported folder f: the t-th material given folder f takes file
  ``order[t mod N]`` of its N sorted map files, ``order`` =
  ``seeded_rng(index f of STREAM_IMPORT).permutation(N)``: every file is used once
  before any is used twice.
- the object of material m (``[scene] objects``, n of them): scheme ``cycle``: m mod n;
  ``random``: (index m of STREAM_OBJECT) mod n (the bias of a 63-bit word mod n is below
  n / 2^63). Drawn per material: a material's maps are projected through its object's
  G-buffer and stored once for all its lightings.
- environment lighting (``[lighting] source = "environment"``): the lightings of material m
  are drawn jointly from ``seeded_rng(index m of STREAM_ENVIRONMENT)``: L map indices
  (``integers(E)``, into the E maps sorted by path), then L rotations and L intensities (``random`` mapped linearly onto
  their ranges: a multiply-add, the same bits on every machine). The sun's angles are planned
  as for a sun-lit spec (the same draws) but not used.

Use :func:`seeded_rng` to turn any of these seeds into a ``numpy.random.Generator``.
"""

from __future__ import annotations

import copy
import os
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from functools import cached_property

import numpy as np

from pipeline.dataset.spec import DEFAULT_OBJECTS, DatasetSpec
from pipeline.dataset.spec_file import environment_files
from pipeline.dataset.spec_rules import list_map_files
from pipeline.errors import ShaderballError, quoted
from sky.portable import asin_deg, sin_deg
from sky.sampling import unit_points

#: The plan format: what a plan digest is a digest of. 2 (shaderball 0.2.0): sun elevations
#: come from :mod:`sky.portable`'s sin and arcsin, the same bits on every machine. 1 (0.1.0)
#: used numpy's vectorised arcsin, whose last bits depend on the CPU: a format-1 dataset
#: is refused on resume rather than mixed (pipeline.run.out_folder.check_same_installation).
PLAN_FORMAT = 2

STREAM_MATERIAL = 1
STREAM_LIGHTS = 2
STREAM_RENDER = 3
STREAM_SVBRDF = 4
STREAM_IMPORT = 5
STREAM_OBJECT = 6
STREAM_ENVIRONMENT = 7

KIND_UNIFORM = "uniform"
KIND_SVBRDF = "svbrdf"

#: render_seed packs (m, l) as m * RENDER_STRIDE + l before mixing: injective because
#: lights_per_material <= 1000 and materials <= 10^6 (so the packed value < 2^32).
RENDER_STRIDE = 1000

_U64 = np.uint64
_U32 = np.uint32


def material_id(material_index: int) -> str:
    return f"m{material_index:06d}"


def sample_id(material_index: int, light_index: int) -> str:
    return f"{material_id(material_index)}_l{light_index}"


def shard_id(shard_index: int) -> str:
    return f"s{shard_index:05d}"


def seeded_rng(seed: int) -> np.random.Generator:
    """The generator every consumer of a plan seed uses: PCG64 seeded with ``seed``."""
    return np.random.Generator(np.random.PCG64(seed))


def stream_key(spec_seed: int, stream: int) -> int:
    """The 64-bit key of a stream: ``SeedSequence(spec_seed, spawn_key=(stream,))``."""
    state = np.random.SeedSequence(spec_seed, spawn_key=(stream,)).generate_state(1, _U64)
    return int(state[0])


def _mix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64's finaliser: a bijection of uint64 that scatters neighbouring inputs."""
    x = (x ^ (x >> _U64(30))) * _U64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> _U64(27))) * _U64(0x94D049BB133111EB)
    return x ^ (x >> _U64(31))


def _mix32(x: np.ndarray) -> np.ndarray:
    """A 32-bit bijective integer hash (Wellons' lowbias32)."""
    x = x ^ (x >> _U32(16))
    x = x * _U32(0x7FEB352D)
    x = x ^ (x >> _U32(15))
    x = x * _U32(0x846CA68B)
    return x ^ (x >> _U32(16))


def index_seeds(spec_seed: int, stream: int, indices) -> np.ndarray:
    """63-bit seeds (uint64 array) of ``indices`` in ``stream``: mix64(key + index) >> 1."""
    key = _U64(stream_key(spec_seed, stream))
    with np.errstate(over="ignore"):
        return _mix64(np.asarray(indices, dtype=_U64) + key) >> _U64(1)


def render_seeds(spec_seed: int, material_indices, light_indices) -> np.ndarray:
    """32-bit render seeds (uint32 array) of (material, light) pairs, broadcast.

    mix32(key32 + m * 1000 + l): distinct for every sample of a dataset.
    """
    key = _U32(stream_key(spec_seed, STREAM_RENDER) & 0xFFFFFFFF)
    packed = np.asarray(material_indices, dtype=_U32) * _U32(RENDER_STRIDE) + np.asarray(light_indices, dtype=_U32)
    with np.errstate(over="ignore"):
        return _mix32(packed + key)


@dataclass(frozen=True, slots=True)
class SamplePlan:
    """One render: a material under one lighting."""

    material_index: int
    light_index: int
    material_id: str
    sample_id: str
    shard_index: int
    kind: str  # "uniform" or "svbrdf"
    svbrdf_family: str | None  # procedural family, for a procedural SVBRDF
    svbrdf_file: str | None  # absolute path of the imported map file, for an imported one
    material_seed: int  # 63-bit; seeded_rng(material_seed) samples the material
    light_seed: int  # 63-bit; the material's joint light draw (light_index picks this one)
    render_seed: int  # 32-bit; mi.render(..., seed=render_seed)
    elevation_deg: float
    azimuth_deg: float
    turbidity: float
    #: The object (a built-in name or a mesh file's absolute path) and, for environment
    #: lighting, the map's absolute path, its rotation and intensity (None under the sun).
    object: str = DEFAULT_OBJECTS[0]
    environment: str | None = None
    rotation_deg: float | None = None
    intensity: float | None = None

    @property
    def shard_id(self) -> str:
        return shard_id(self.shard_index)

    def to_dict(self) -> dict:
        return _without_scene_defaults(asdict(self))

    def requested_lighting(self) -> dict:
        """The lighting this sample asks for, as its record's ``lighting.requested`` says it: the
        sun's angles and turbidity, or the map's base name, its rotation and intensity."""
        if self.environment is not None:
            return {
                "environment": os.path.basename(self.environment),
                "rotation_deg": self.rotation_deg,
                "intensity": self.intensity,
            }
        return {"elevation_deg": self.elevation_deg, "azimuth_deg": self.azimuth_deg, "turbidity": self.turbidity}

    @property
    def object_name(self) -> str:
        """The object as a record names it: a built-in's name, a mesh file's base name."""
        return os.path.basename(self.object)


@dataclass(frozen=True)
class MaterialPlan:
    """A material and all its lightings; its maps are sampled once from ``material_seed``.

    Per-lighting values are stored as tuples indexed by light index; :attr:`samples`
    gives them as :class:`SamplePlan` records (built on first access: building 50,000
    of them eagerly would double the planning time of the paper spec).
    """

    material_index: int
    material_id: str
    shard_index: int
    kind: str  # "uniform" or "svbrdf"
    svbrdf_family: str | None
    svbrdf_file: str | None
    material_seed: int
    light_seed: int
    render_seeds: tuple[int, ...]
    elevation_deg: tuple[float, ...]
    azimuth_deg: tuple[float, ...]
    turbidity: tuple[float, ...]
    object: str = DEFAULT_OBJECTS[0]
    #: Environment lighting only (empty under the sun): per lighting.
    environment: tuple[str, ...] = ()
    rotation_deg: tuple[float, ...] = ()
    intensity: tuple[float, ...] = ()

    @property
    def shard_id(self) -> str:
        return shard_id(self.shard_index)

    @property
    def n_lights(self) -> int:
        return len(self.render_seeds)

    @cached_property
    def samples(self) -> tuple[SamplePlan, ...]:
        m, mid = self.material_index, self.material_id
        return tuple(
            SamplePlan(
                m,
                l,
                mid,
                f"{mid}_l{l}",
                self.shard_index,
                self.kind,
                self.svbrdf_family,
                self.svbrdf_file,
                self.material_seed,
                self.light_seed,
                self.render_seeds[l],
                self.elevation_deg[l],
                self.azimuth_deg[l],
                self.turbidity[l],
                self.object,
                *((self.environment[l], self.rotation_deg[l], self.intensity[l]) if self.environment else ()),
            )
            for l in range(len(self.render_seeds))
        )

    def to_dict(self) -> dict:
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        for key in ("render_seeds", "elevation_deg", "azimuth_deg", "turbidity", *SCENE_TUPLES):
            out[key] = list(out[key])
        return _without_scene_defaults(out)


#: A material's per-lighting tuples of environment lighting.
SCENE_TUPLES = ("environment", "rotation_deg", "intensity")


def _without_scene_defaults(out: dict) -> dict:
    """A plan entry without its scene's keys at their defaults (the shaderball, the sun): a spec
    that names neither plans the same entries, and the same plan digest, as before they existed."""
    if out.get("object") == DEFAULT_OBJECTS[0]:
        del out["object"]
    for key in SCENE_TUPLES:
        if out.get(key) in (None, []):
            del out[key]
    return out


@dataclass(frozen=True, slots=True)
class ShardPlan:
    """The unit of work: consecutive materials, all their lightings."""

    shard_index: int
    shard_id: str
    materials: tuple[MaterialPlan, ...]

    @property
    def samples(self) -> tuple[SamplePlan, ...]:
        return tuple(s for m in self.materials for s in m.samples)

    @property
    def n_renders(self) -> int:
        return sum(m.n_lights for m in self.materials)


def list_imported_maps(spec: DatasetSpec) -> dict[str, tuple[str, ...]]:
    """Sorted map-file names of each imported SVBRDF folder of ``spec``.

    The one place the planner touches the file system (a directory listing). Pass its
    result to :func:`plan_dataset` to keep planning itself pure.
    """
    return {folder: list_map_files(folder) for folder in spec.materials.svbrdf_folders}


def _svbrdf_arrays(spec: DatasetSpec, imported: Mapping[str, Sequence[str]]):
    """(sources, file_orders, source_of, use_of): ``source_of[m]`` is the index in ``sources``
    of material m's SVBRDF source (-1: a uniform material), ``use_of[m]`` how many SVBRDF
    materials drew that source before it (the t of the module doc). Vectorised: the j-th
    chosen material takes source j mod S, and is that source's (j div S)-th use."""
    n = spec.dataset.materials
    k = spec.dataset.n_svbrdf
    seed = spec.dataset.seed
    families = list(spec.materials.svbrdf_families)
    folders = list(spec.materials.svbrdf_folders)
    sources = [("family", f) for f in families] + [("folder", i) for i in range(len(folders))]
    file_orders: dict[int, list[str]] = {}
    source_of = np.full(n, -1, dtype=np.int32)
    use_of = np.zeros(n, dtype=np.int32)
    if k == 0:
        return sources, file_orders, source_of, use_of
    for i, folder in enumerate(folders):
        names = sorted(imported.get(folder, ()))
        if not names:
            raise ShaderballError(f"materials.svbrdf_folders: {quoted(folder)} holds no map file to import")
        order = seeded_rng(int(index_seeds(seed, STREAM_IMPORT, i))).permutation(len(names))
        file_orders[i] = [os.path.join(folder, names[j]) for j in order.tolist()]
    chosen = seeded_rng(int(index_seeds(seed, STREAM_SVBRDF, 0))).permutation(n)[:k]
    j = np.arange(k)
    source_of[chosen] = j % len(sources)
    use_of[chosen] = j // len(sources)
    return sources, file_orders, source_of, use_of


def _svbrdf_assignment(
    spec: DatasetSpec, imported: Mapping[str, Sequence[str]]
) -> dict[int, tuple[str | None, str | None]]:
    """material index -> (family, file) for every SVBRDF material (see module doc)."""
    plan = Plan(spec, imported)
    return {m: plan.svbrdf_source(m) for m in np.flatnonzero(plan.source_of >= 0).tolist()}


def _light_arrays(spec: DatasetSpec, light_seeds: np.ndarray):
    """(elevation_deg, azimuth_deg, turbidity), each (materials, lights_per_material).

    The unit-cube points come from ``sky.sampling.unit_points`` per material (so the
    scheme is sky's); they are mapped to angles here in one vectorised pass with the same
    arithmetic as ``sky.sampling.lights_from_unit_cube``, because building 50,000
    ``sky.Light`` objects one material at a time takes about a second for the paper spec.
    tests/test_plan.py checks the result against ``sky.sample_lights`` itself, and that a
    shard's values are the same computed alone or with every other material.
    """
    ranges = spec.lighting.to_lighting_ranges()
    n_lights = spec.dataset.lights_per_material
    u = np.stack([unit_points(seeded_rng(int(s)), n_lights, ranges.scheme) for s in light_seeds.tolist()])
    el_lo, el_hi = ranges.elevation_deg
    az_lo, az_hi = ranges.azimuth_deg
    t_lo, t_hi = ranges.turbidity
    if ranges.scheme == "uniform_angles":
        elevation = el_lo + u[..., 0] * (el_hi - el_lo)
    else:
        z_lo, z_hi = sin_deg(float(el_lo)), sin_deg(float(el_hi))
        z = z_lo + u[..., 0] * (z_hi - z_lo)
        elevation = np.clip(asin_deg(np.clip(z, -1.0, 1.0)), el_lo, el_hi)
    azimuth = az_lo + u[..., 1] * (az_hi - az_lo)
    turbidity = np.clip(t_lo + u[..., 2] * (t_hi - t_lo), t_lo, t_hi)
    if spec.lighting.turbidity_per == "material":
        turbidity = np.broadcast_to(turbidity[:, :1], turbidity.shape)
    return elevation, azimuth, turbidity


class Plan(Sequence):
    """Every shard of a spec, in order: a sequence of :class:`ShardPlan` made on demand.

    Planning is lazy: making the plan costs the SVBRDF assignment only (two
    int32 arrays of ``materials`` entries); each shard's materials, seeds and lightings are
    computed when the shard is asked for, and not kept. A plan of 10 million renders is made
    in well under a second and a few tens of MB (``scripts/plan_scale.py``).
    Counts, shard ids and sample ids come from arithmetic (:meth:`shard_counts`,
    :meth:`shard_sample_ids`, :meth:`summary`), so a build's bookkeeping never builds the
    whole plan. Iterating it builds every shard once (a build's plan digest does that,
    streamed).

    Values are those of one vectorised computation over every material: seeds and angles
    are element-wise (the test compares a shard made alone with the whole).
    """

    def __init__(self, spec: DatasetSpec, imported: Mapping[str, Sequence[str]]):
        self.spec = spec
        self.sources, self.file_orders, self.source_of, self.use_of = _svbrdf_arrays(spec, imported)
        self._kept: list[ShardPlan] | None = None

    def kept(self) -> Plan:
        """This plan with every shard made now, once, and kept: for a reader that visits every
        shard more than once (validate holds every record anyway)."""
        kept = copy.copy(self)
        kept._kept = [self.shard(i) for i in range(len(self))]
        return kept

    # -- Sequence
    def __len__(self) -> int:
        return self.spec.dataset.n_shards

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self.shard(i) for i in range(*index.indices(len(self)))]
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError(f"shard index {index} out of range")
        return self.shard(index)

    def __eq__(self, other) -> bool:
        if not isinstance(other, Sequence) or len(other) != len(self):
            return NotImplemented if not isinstance(other, Sequence) else False
        return all(a == b for a, b in zip(self, other))

    __hash__ = None

    def __repr__(self) -> str:
        ds = self.spec.dataset
        return f"Plan({ds.name!r}: {len(self)} shards, {ds.materials} materials, {ds.n_renders} renders)"

    # -- arithmetic
    def material_range(self, index: int) -> range:
        ds = self.spec.dataset
        return range(index * ds.shard_size, min((index + 1) * ds.shard_size, ds.materials))

    def shard_counts(self) -> list[tuple[str, int]]:
        """(shard id, renders) of every shard, without planning them."""
        lights = self.spec.dataset.lights_per_material
        return [(shard_id(i), len(self.material_range(i)) * lights) for i in range(len(self))]

    def shard_sample_ids(self, index: int) -> list[str]:
        """The sample ids of shard ``index`` in plan order, without planning it."""
        lights = range(self.spec.dataset.lights_per_material)
        return [sample_id(m, l) for m in self.material_range(index) for l in lights]

    @property
    def n_renders(self) -> int:
        return self.spec.dataset.n_renders

    def svbrdf_source(self, m: int) -> tuple[str | None, str | None]:
        """(family, file) of material ``m`` ((None, None) for a uniform one)."""
        src = int(self.source_of[m])
        if src < 0:
            return None, None
        what, which = self.sources[src]
        if what == "family":
            return which, None
        files = self.file_orders[which]
        return None, files[int(self.use_of[m]) % len(files)]

    def summary(self) -> dict:
        """:func:`plan_summary` of this plan, from the arrays."""
        svbrdf = self.source_of >= 0
        per_source = (
            np.bincount(self.source_of[svbrdf], minlength=len(self.sources))
            if svbrdf.any()
            else np.zeros(len(self.sources), dtype=np.int64)
        )
        sources: Counter = Counter()
        for (what, which), count in zip(self.sources, per_source.tolist()):
            if count:
                key = f"family:{which}" if what == "family" else f"folder:{os.path.dirname(self.file_orders[which][0])}"
                sources[key] += count
        n_svbrdf = int(svbrdf.sum())
        return {
            "shards": len(self),
            "materials": self.spec.dataset.materials,
            "renders": self.n_renders,
            "uniform": self.spec.dataset.materials - n_svbrdf,
            "svbrdf": n_svbrdf,
            "svbrdf_sources": dict(sorted(sources.items())),
            **self._scene_counts(),
        }

    def _scene_counts(self) -> dict:
        """Materials per object, and the environment maps drawn from: only where the spec names
        other objects or lights (a default spec's counts are as they were)."""
        out = {}
        if self.spec.scene.objects != DEFAULT_OBJECTS:
            drawn = Counter(_object_choices(self.spec, np.arange(self.spec.dataset.materials)))
            out["objects"] = {os.path.basename(o): drawn[o] for o in self.spec.scene.objects}
        if self.environments:
            out["environments"] = [os.path.basename(path) for path in self.environments]
        return out

    # -- one shard
    def shard(self, index: int) -> ShardPlan:
        if self._kept is not None:
            return self._kept[index]
        ds = self.spec.dataset
        ms = self.material_range(index)
        m_all = np.arange(ms.start, ms.stop)
        material_seeds = index_seeds(ds.seed, STREAM_MATERIAL, m_all).tolist()
        light_seeds = index_seeds(ds.seed, STREAM_LIGHTS, m_all)
        r_seeds = render_seeds(ds.seed, m_all[:, None], np.arange(ds.lights_per_material)[None, :]).tolist()
        elevation, azimuth, turbidity = (a.tolist() for a in _light_arrays(self.spec, light_seeds))
        light_seeds = light_seeds.tolist()
        objects = _object_choices(self.spec, m_all)
        materials = []
        for i, m in enumerate(ms):
            family, file = self.svbrdf_source(m)
            kind = KIND_SVBRDF if self.source_of[m] >= 0 else KIND_UNIFORM
            materials.append(
                MaterialPlan(
                    m,
                    material_id(m),
                    index,
                    kind,
                    family,
                    file,
                    material_seeds[i],
                    light_seeds[i],
                    tuple(r_seeds[i]),
                    tuple(elevation[i]),
                    tuple(azimuth[i]),
                    tuple(turbidity[i]),
                    objects[i],
                    *self._environment_draw(m),
                )
            )
        return ShardPlan(index, shard_id(index), tuple(materials))

    @cached_property
    def environments(self) -> tuple[str, ...]:
        """The environment maps lightings draw from, in draw order (empty under the sun)."""
        return environment_files(self.spec) if self.spec.lighting.source == "environment" else ()

    def _environment_draw(self, m: int) -> tuple[tuple, ...]:
        """(maps, rotations, intensities) of material ``m``'s lightings; () under the sun."""
        if not self.environments:
            return ()
        lighting, n = self.spec.lighting, self.spec.dataset.lights_per_material
        rng = seeded_rng(int(index_seeds(self.spec.dataset.seed, STREAM_ENVIRONMENT, [m])[0]))
        which = rng.integers(len(self.environments), size=n).tolist()
        (r_lo, r_hi), (s_lo, s_hi) = lighting.rotation_deg, lighting.intensity
        rotation = (r_lo + rng.random(n) * (r_hi - r_lo)).tolist()
        intensity = np.clip(s_lo + rng.random(n) * (s_hi - s_lo), s_lo, s_hi).tolist()
        return tuple(self.environments[k] for k in which), tuple(rotation), tuple(intensity)


def _object_choices(spec: DatasetSpec, m_all: np.ndarray) -> list[str]:
    """The object of each material of ``m_all`` (the module docstring's rule)."""
    objects = spec.scene.objects
    if len(objects) == 1:
        return [objects[0]] * len(m_all)
    if spec.scene.scheme == "cycle":
        picks = m_all % len(objects)
    else:
        picks = index_seeds(spec.dataset.seed, STREAM_OBJECT, m_all) % np.uint64(len(objects))
    return [objects[int(k)] for k in picks.tolist()]


def plan_dataset(spec: DatasetSpec, imported: Mapping[str, Sequence[str]] | None = None) -> Plan:
    """Every shard of ``spec``, in order (a :class:`Plan`: shards are made on demand);
    deterministic and pure.

    ``imported`` maps each of ``spec.materials.svbrdf_folders`` to its map-file names
    (as :func:`list_imported_maps` returns); when None and the spec has folders, they
    are listed here.
    """
    if imported is None:
        imported = list_imported_maps(spec) if spec.materials.svbrdf_folders else {}
    return Plan(spec, imported)


def iter_samples(plans: Sequence[ShardPlan]):
    """Every SamplePlan, in plan order (shard, material, light)."""
    for shard in plans:
        for material in shard.materials:
            yield from material.samples


def plan_summary(plans: Plan) -> dict:
    """Counts: shards, materials, renders, uniform and SVBRDF materials, SVBRDF sources."""
    return plans.summary()
