"""Dataset specs: a TOML file parsed into frozen, checked dataclasses.

A spec has six sections, one dataclass each::

    [dataset]    DatasetSection    name, version, seed, counts, uniform/SVBRDF split, shard size
    [materials]  MaterialsSection  uniform-material ranges, SVBRDF sources, texture size
    [scene]      SceneSection      the objects the materials are shown on, how one is drawn
    [lighting]   LightingSection   sun and sky (elevation/azimuth/turbidity ranges, scheme, sun
                                   form) or HDR environment maps (files, rotation, intensity)
    [render]     RenderSettings    resolution, spp, max depth, integrator, Mitsuba variant, sampler, ...
                                   (the renderer's settings type, pipeline.render.settings)
    [storage]    StorageSection    EXR compression, stored layers, texture-space maps, half maps

Each section checks its own fields in ``__post_init__`` (so a section built from Python
is checked too) and raises :class:`SpecError`, a :class:`ShaderballError` whose message
reads ``<file>: <section>.<field>: <value> is not allowed; <what is allowed>``.
Unknown sections and keys are errors (a typo must never be silently ignored); a missing
key takes its documented default, except the required ``dataset.name``, ``dataset.seed``
and ``dataset.materials``.

Reading, parsing, the canonical form, the digest and the reference page
(``docs/spec-fields.md``, generated from the field metadata below) are
:mod:`pipeline.dataset.spec_file`'s.

This module is pure: it checks that SVBRDF folders, mesh files and environment maps exist,
nothing else (their contents are checked when they are loaded, and digested into the spec
digest by :mod:`pipeline.dataset.spec_file`). No Mitsuba, no dask.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, fields
from typing import ClassVar

from geometry.meshfile import MESH_SUFFIXES
from geometry.objects import BUILTIN_OBJECTS
from materials import SVBRDF_FAMILIES, UNIFORM_LIMITS, UniformRanges
from materials.brdf_ref import DEFAULT_MODEL, MODELS
from pipeline.dataset.spec_rules import (
    Files,
    Folders,
    Section,
    SpecError,
)
from pipeline.fields import Checked, field
from pipeline.fields.rules import (
    Bool,
    Choice,
    Float,
    Int,
    Pair,
    StrList,
    Text,
)
from pipeline.image.formats import EXR_COMPRESSIONS
from pipeline.render.limits import DEFAULT_RR_DEPTH, RESOLUTION_RANGE  # noqa: F401 - RESOLUTION_RANGE: the spec's
from pipeline.render.settings import RenderSettings
from sky.emitter import SUN_MODES
from sky.environment import ENVIRONMENT_SUFFIXES, ROTATION_RANGE, SCALE_RANGE
from sky.lighting import (
    AZIMUTH_BOUNDS,
    AZIMUTH_TURN,
    ELEVATION_RANGE,
    MAX_AZIMUTH_SPAN_DEG,
    SCHEMES,
    TURBIDITY_RANGE,
    LightingRanges,
)

#: Procedural SVBRDF families, used when ``materials.SVBRDF_FAMILIES`` can't be imported.
#: Keep in sync with materials/ (a test compares them when materials/ is importable).
FALLBACK_SVBRDF_FAMILIES: tuple[str, ...] = ("stains", "tiles", "bricks", "brushed_metal", "worn_paint", "stones")


#: Screen-space map layers the storage stage can write (pipeline.store.exr layer names).
MAP_LAYERS: tuple[str, ...] = ("diffuse", "specular", "roughness", "normal", "mask")
#: Geometry layers a spec may ask for besides the maps (pipeline.store.exr.GEOMETRY_LAYERS): the
#: object's world-space shading normal and its z-depth in metres, always float32. Not stored
#: by default, so a spec that names none keeps its digest and its files.
GEOMETRY_LAYERS: tuple[str, ...] = ("geometry_normal", "depth")

#: Upper bounds that keep ids fixed-width: "m" + 6 digits, "s" + 5 digits (pipeline.store.layout).
MAX_MATERIALS = 1_000_000
MAX_SHARDS = 100_000
#: Renders in a dataset: planning is lazy (pipeline.dataset.plan.Plan), so this is set by
#: what the files hold: ~3 kB of manifest per render.
MAX_RENDERS = 10_000_000
#: Renders in a shard: its marker (~3 kB a render) is read whole.
MAX_SHARD_RENDERS = 100_000

SEED_MAX = 2**63 - 1


def svbrdf_family_names() -> tuple[str, ...]:
    """The procedural SVBRDF families (materials.SVBRDF_FAMILIES)."""
    return tuple(SVBRDF_FAMILIES)


# --------------------------------------------------------------------------- sections


@dataclass(frozen=True)
class DatasetSection(Section):
    """[dataset]: what is built, how much of it, from which seed."""

    SECTION: ClassVar[str] = "dataset"

    name: str = field(
        rule=Text(r"[a-z0-9_-]{1,64}", "1 to 64 characters from a-z, 0-9, _ and -"),
        doc="Dataset name; used in file names and the published description.",
    )
    seed: int = field(
        rule=Int(0, SEED_MAX), doc="Root of every random stream of the dataset (see the seed derivation below)."
    )
    materials: int = field(
        rule=Int(1, MAX_MATERIALS), doc="Number of materials; ids m000000 to m(materials-1).", unit="materials"
    )
    version: str = field(
        "1",
        rule=Text(
            r"[A-Za-z0-9][A-Za-z0-9._+-]{0,31}",
            "1 to 32 characters from A-Z, a-z, 0-9, . _ + -, starting with a letter or digit",
        ),
        doc="Version of the dataset, recorded in its description.",
    )
    lights_per_material: int = field(
        5,
        rule=Int(1, 1000),
        doc="Lightings (sun direction + turbidity) rendered per material; the paper uses 5.",
        unit="lightings",
    )
    svbrdf_fraction: float = field(
        0.5,
        rule=Float(0.0, 1.0),
        doc="Share of materials that are spatially varying; "
        "exactly floor(fraction x materials + 0.5) of them. "
        "The paper: 0.5.",
    )
    shard_size: int = field(
        20,
        rule=Int(1, MAX_MATERIALS),
        doc="Materials per shard, the unit of work; all lightings of a "
        "material are in its shard. Changes grouping only, never "
        "seeds. At most 100000 shards.",
        unit="materials",
    )

    @property
    def n_svbrdf(self) -> int:
        """How many materials are SVBRDF: floor(fraction * materials + 0.5) (ties round up)."""
        return int(math.floor(self.svbrdf_fraction * self.materials + 0.5))

    @property
    def n_shards(self) -> int:
        return -(-self.materials // self.shard_size)

    @property
    def n_renders(self) -> int:
        return self.materials * self.lights_per_material

    def check_cross(self):
        if self.n_shards > MAX_SHARDS:
            need = -(-self.materials // MAX_SHARDS)
            raise SpecError(
                "dataset",
                "shard_size",
                self.shard_size,
                f"at least {need} with {self.materials} materials (at most {MAX_SHARDS} shards)",
            )
        if self.n_renders > MAX_RENDERS:
            raise SpecError(
                "dataset",
                "lights_per_material",
                self.lights_per_material,
                f"at most {MAX_RENDERS // self.materials} with {self.materials} materials: "
                f"materials x lights_per_material = {self.n_renders} renders, and a dataset "
                f"holds at most {MAX_RENDERS} (its manifest alone would be "
                f"~{self.n_renders * 3000 // 10**9} GB)",
            )
        if self.shard_size * self.lights_per_material > MAX_SHARD_RENDERS:
            raise SpecError(
                "dataset",
                "shard_size",
                self.shard_size,
                f"at most {MAX_SHARD_RENDERS // self.lights_per_material} with "
                f"{self.lights_per_material} lightings per material: a shard holds at most "
                f"{MAX_SHARD_RENDERS} renders (its marker is read whole)",
            )


def _uniform(name: str, *, doc: str, unit: str = ""):
    """A [materials] field that is ``materials.UniformRanges``' field ``name``: its default
    and its limits (UNIFORM_LIMITS) are the sampler's, declared there once."""
    default = next(f.default for f in fields(UniformRanges) if f.name == name)
    rule = Pair if isinstance(default, tuple) else Float
    return field(default, rule=rule(*UNIFORM_LIMITS[name]), doc=doc, unit=unit)


@dataclass(frozen=True)
class MaterialsSection(Section):
    """[materials]: ranges of uniform materials, sources of spatially varying ones."""

    SECTION: ClassVar[str] = "materials"

    # Uniform materials: the fields of materials.UniformRanges (a test keeps them equal),
    # each with its default and limits (_uniform). The model: a dielectric (grey specular of a few percent,
    # coloured diffuse) or, with probability metal_probability, a metal (coloured
    # specular, almost no diffuse); colours drawn in HSV with V in sRGB-encoded units.
    roughness: tuple[float, float] = _uniform(
        "roughness",
        doc="Range of a uniform material's roughness r, drawn uniformly (GGX alpha = r^2). "
        "Below ~0.05 highlights are near-mirror images of the sun and noise grows sharply.",
    )
    metal_probability: float = _uniform(
        "metal_probability",
        doc="Probability that a uniform material is a metal (coloured specular, ~no diffuse).",
        unit="probability",
    )
    dielectric_specular: tuple[float, float] = _uniform(
        "dielectric_specular",
        doc="Range of a dielectric's grey specular albedo (water ~0.02, plastics ~0.04-0.05, gems ~0.08+).",
        unit="linear albedo",
    )
    diffuse_value_srgb: tuple[float, float] = _uniform(
        "diffuse_value_srgb",
        doc="Range of a dielectric's diffuse brightness, HSV value in sRGB-encoded units "
        "(0.15: 0.02 linear, charcoal; 0.95: 0.89 linear, fresh snow).",
        unit="sRGB-encoded value",
    )
    diffuse_saturation: tuple[float, float] = _uniform(
        "diffuse_saturation",
        doc="Range of a dielectric's diffuse saturation (HSV).",
    )
    metal_value_srgb: tuple[float, float] = _uniform(
        "metal_value_srgb",
        doc="Range of a metal's specular brightness, HSV value in sRGB-encoded units "
        "(0.55: 0.26 linear, dark titanium-like metals; 1.0: silver).",
        unit="sRGB-encoded value",
    )
    metal_saturation: tuple[float, float] = _uniform(
        "metal_saturation",
        doc="Range of a metal's specular saturation (HSV); gold and copper are ~0.4-0.5.",
    )
    metal_hue: tuple[float, float] = _uniform(
        "metal_hue",
        doc="Range of a metal's specular hue (HSV, 0 = red, 1/6 = yellow): copper, gold and "
        "brass lie in ~0.03-0.15; greys (low saturation) are hue-neutral.",
    )
    metal_diffuse_fraction: tuple[float, float] = _uniform(
        "metal_diffuse_fraction",
        doc="Range of a metal's diffuse albedo as a fraction of the room left, 1 - specular (dirt, oxide).",
    )
    flat_normal_probability: float = _uniform(
        "flat_normal_probability",
        doc="Probability that a uniform material's normal is flat, (0, 0, 1).",
        unit="probability",
    )
    normal_tilt_max_deg: float = _uniform(
        "normal_tilt_max_deg",
        doc="Largest tilt from (0, 0, 1) of a non-flat uniform normal; the tilt is uniform in "
        "solid angle, towards a uniform azimuth.",
        unit="degrees",
    )
    svbrdf_families: tuple[str, ...] = field(
        rule=StrList(
            svbrdf_family_names,
            "procedural family names",
            doc_allowed="a list of distinct names from materials.SVBRDF_FAMILIES",
        ),
        factory=svbrdf_family_names,
        doc_default="all of materials.SVBRDF_FAMILIES",
        doc="Procedural SVBRDF families SVBRDF materials are drawn from (default: all). "
        "May be empty when svbrdf_folders is not.",
    )
    svbrdf_folders: tuple[str, ...] = field(
        (),
        rule=Folders(),
        doc="Folders of imported SVBRDF maps in Deschaintre et al. 2018's layout "
        "(one .png per material), checked when the spec is read. Stored as "
        "absolute paths in the canonical form.",
    )
    texture_resolution: int = field(
        256, rule=Int(16, 4096), doc="Width and height of a material's texture-space (UV) maps.", unit="texels"
    )
    model: str = field(
        DEFAULT_MODEL,
        rule=Choice(MODELS),
        doc="The BRDF every material is rendered with: shaderball (Cook-Torrance as "
        "published, GGX normalised, energy-conserving) or deschaintre2018 (the same with "
        "the two floors of Deschaintre et al.'s code on GGX D and Smith G1, to match data "
        "rendered by that code; it darkens surfaces with roughness below 0.178, "
        "docs/materials.md). Recorded in each sample's record when not the default.",
    )

    @property
    def has_svbrdf_source(self) -> bool:
        return bool(self.svbrdf_families or self.svbrdf_folders)

    def to_uniform_ranges(self):
        """The ranges as ``materials.UniformRanges``."""
        return UniformRanges(**{name: getattr(self, name) for name in UNIFORM_FIELDS})


#: The fields of MaterialsSection passed to materials.UniformRanges.
UNIFORM_FIELDS: tuple[str, ...] = (
    "roughness",
    "metal_probability",
    "dielectric_specular",
    "diffuse_value_srgb",
    "diffuse_saturation",
    "metal_value_srgb",
    "metal_saturation",
    "metal_hue",
    "metal_diffuse_fraction",
    "flat_normal_probability",
    "normal_tilt_max_deg",
)


#: How a material's object is drawn (docs/scenes.md): per material, since a material's
#: screen-space maps are projected through its object's G-buffer and stored once.
OBJECT_SCHEMES: tuple[str, ...] = ("random", "cycle")
#: The one object of a spec without a [scene] section.
DEFAULT_OBJECTS: tuple[str, ...] = (BUILTIN_OBJECTS[0],)


@dataclass(frozen=True)
class SceneSection(Section):
    """[scene]: the objects the materials are shown on."""

    SECTION: ClassVar[str] = "scene"

    objects: tuple[str, ...] = field(
        DEFAULT_OBJECTS,
        rule=Files(MESH_SUFFIXES, "objects", names=BUILTIN_OBJECTS),
        doc="Objects a material is drawn on: built-in ones ("
        + ", ".join(f'"{n}"' for n in BUILTIN_OBJECTS)
        + ") or mesh files (OBJ, PLY, STL, glTF/GLB), each normalised to the shaderball's size and stood on "
        "the ground, framed by the same camera rule; a mesh's own UVs are kept when usable, else made by "
        "xatlas. Mesh files are checked and digested when the spec is read: changing one is a different "
        "dataset. Stored as absolute paths in the canonical form.",
    )
    scheme: str = field(
        OBJECT_SCHEMES[0],
        rule=Choice(OBJECT_SCHEMES),
        doc="How each material's object is chosen among objects: random (uniformly, from the material's own "
        "seeded stream) or cycle (material m takes object m mod len(objects): equal shares).",
    )

    def check_cross(self):
        if not self.objects:
            raise self.field_error("objects", [], "at least one object")


#: Sun-direction sampling schemes, as the spec reference words them (a test keeps them equal to sky's).
FALLBACK_LIGHT_SCHEMES: tuple[str, ...] = ("uniform_hemisphere", "uniform_angles", "stratified", "sobol")


def light_scheme_names() -> tuple[str, ...]:
    """The sun-sampling schemes (sky.lighting.SCHEMES)."""
    return tuple(SCHEMES)


#: What lights a scene (docs/scenes.md).
LIGHT_SOURCES: tuple[str, ...] = ("sun_sky", "environment")
#: The [lighting] keys of environment lighting (the others are the sun and sky's).
ENVIRONMENT_KEYS: tuple[str, ...] = ("source", "environments", "rotation_deg", "intensity")

#: How the sun is given to Mitsuba (defined in sky.emitter).
SUN_FORMS: tuple[str, ...] = SUN_MODES


@dataclass(frozen=True)
class LightingSection(Section):
    """[lighting]: the Hosek-Wilkie sun and sky each render is lit by."""

    SECTION: ClassVar[str] = "lighting"

    elevation_deg: tuple[float, float] = field(
        (5.0, 90.0),
        rule=Pair(*ELEVATION_RANGE),
        doc="Range of the sun's elevation above the horizon. Mitsuba's RGB sunsky is black at "
        "0, its sun's blue channel is negative below ~2.4 and its sky slightly negative near "
        "the horizon for suns up to ~7 (turbidity 10): lights below the measured floor "
        "(2.5 to 7.0 by turbidity; docs/sky.md) are raised to it, and the move is recorded.",
        unit="degrees",
    )
    azimuth_deg: tuple[float, float] = field(
        AZIMUTH_TURN,
        rule=Pair(*AZIMUTH_BOUNDS, max_span=MAX_AZIMUTH_SPAN_DEG),
        doc="Range of the sun's azimuth, counter-clockwise from +x seen from above "
        "(0: from the image's right, 90: from behind, 270: from the camera's side).",
        unit="degrees",
    )
    turbidity: tuple[float, float] = field(
        TURBIDITY_RANGE,
        rule=Pair(*TURBIDITY_RANGE),
        doc="Range of the atmosphere's turbidity (Hosek-Wilkie; Mitsuba accepts 1 to 10).",
    )
    scheme: str = field(
        "uniform_hemisphere",
        rule=Choice(
            light_scheme_names,
            doc_allowed="one of " + ", ".join(f'"{x}"' for x in FALLBACK_LIGHT_SCHEMES) + " (sky.SCHEMES)",
        ),
        doc="How the lightings of a material are drawn (all of them jointly, see below): "
        "uniform_hemisphere (uniform in solid angle over the band; the paper), "
        "uniform_angles (uniform in elevation and azimuth degrees), stratified (Latin "
        "hypercube over sin(elevation), azimuth and turbidity), sobol (scrambled Sobol' "
        "points). Turbidity is uniform in every scheme.",
    )
    turbidity_per: str = field(
        "material",
        rule=Choice(("material", "light")),
        doc="material: one turbidity per material, shared by all its lightings (the paper: "
        "'a random turbidity per material'; drawn with its first lighting); light: a "
        "turbidity drawn for every lighting.",
    )
    sun: str = field(
        "split",
        rule=Choice(SUN_FORMS),
        doc="Sun representation (pipeline.render.emitter): split (a sky-only sunsky plus a directional "
        "sun of the same irradiance; sky's measured default) or sunsky (one Mitsuba "
        "sunsky emitter, its sun an area light of 0.5358 degrees).",
    )

    source: str = field(
        LIGHT_SOURCES[0],
        rule=Choice(LIGHT_SOURCES),
        doc="What lights the scene: sun_sky (the Hosek-Wilkie sun and sky of the keys above) or environment "
        "(an HDR environment map of environments, drawn per lighting, rotated about the vertical; no sun "
        "and no sky: the keys above are then unused).",
    )
    environments: tuple[str, ...] = field(
        (),
        rule=Files(ENVIRONMENT_SUFFIXES, "environment maps", folders=True),
        doc="With source = environment: lat-long HDR maps (OpenEXR or Radiance .hdr), files or folders of "
        "them, each lighting drawing one uniformly. Checked and digested when the spec is read; stored as "
        "absolute paths in the canonical form.",
    )
    rotation_deg: tuple[float, float] = field(
        ROTATION_RANGE,
        rule=Pair(*ROTATION_RANGE),
        doc="With source = environment: range of the map's rotation about the vertical, counter-clockwise "
        "seen from above, drawn uniformly per lighting.",
        unit="degrees",
    )
    intensity: tuple[float, float] = field(
        (1.0, 1.0),
        rule=Pair(*SCALE_RANGE),
        doc="With source = environment: range of the radiance multiplier, drawn uniformly per lighting "
        "(1: the map's own radiance).",
    )

    def check_cross(self):
        if self.source == "environment" and not self.environments:
            raise self.field_error("environments", [], 'at least one file or folder with source = "environment"')
        if self.source != "environment" and self.environments:
            raise self.field_error(
                "environments", list(self.environments), 'none with source = "sun_sky" (set source = "environment")'
            )

    def to_lighting_ranges(self):
        """The ranges as ``sky.LightingRanges``."""
        return LightingRanges(
            elevation_deg=self.elevation_deg,
            azimuth_deg=self.azimuth_deg,
            turbidity=self.turbidity,
            scheme=self.scheme,
        )


#: The [render] section is the renderer's settings type, declared in pipeline.render.settings.
RenderSection = RenderSettings


@dataclass(frozen=True)
class StorageSection(Section):
    """[storage]: what is written and how."""

    SECTION: ClassVar[str] = "storage"

    compression: str = field(
        "zip", rule=Choice(tuple(EXR_COMPRESSIONS)), doc="EXR compression of every file (all lossless)."
    )
    layers: tuple[str, ...] = field(
        MAP_LAYERS,
        rule=StrList(MAP_LAYERS + GEOMETRY_LAYERS, "map layer names"),
        doc="Screen-space layers stored per material (renders are always stored): the maps, and on "
        "request the object's geometry (geometry_normal: world-space shading normal; depth: metres "
        "from the camera plane; both float32). Canonical order: as listed here.",
    )
    texture_maps: bool = field(True, rule=Bool(), doc="Also store each material's texture-space (UV) maps.")
    maps_half: bool = field(True, rule=Bool(), doc="Store maps as half floats (renders are always float32).")

    def check_cross(self):
        # One canonical order, so ["normal", "diffuse"] and ["diffuse", "normal"] are the
        # same spec with the same digest.
        object.__setattr__(self, "layers", tuple(n for n in MAP_LAYERS + GEOMETRY_LAYERS if n in self.layers))


SECTIONS: dict[str, type[Checked]] = {
    "dataset": DatasetSection,
    "materials": MaterialsSection,
    "scene": SceneSection,
    "lighting": LightingSection,
    "render": RenderSection,
    "storage": StorageSection,
}


@dataclass(frozen=True)
class DatasetSpec:
    """A whole, checked spec. Build one with :func:`parse_spec` or :func:`parse_spec_text`."""

    dataset: DatasetSection
    materials: MaterialsSection = dataclasses.field(default_factory=MaterialsSection)
    scene: SceneSection = dataclasses.field(default_factory=SceneSection)
    lighting: LightingSection = dataclasses.field(default_factory=LightingSection)
    #: Its ``sun`` and ``model`` are filled in from ``lighting.sun`` and ``materials.model``.
    render: RenderSettings = dataclasses.field(default_factory=RenderSettings)
    storage: StorageSection = dataclasses.field(default_factory=StorageSection)

    def __post_init__(self):
        for name, cls in SECTIONS.items():
            if not isinstance(getattr(self, name), cls):
                raise TypeError(f"DatasetSpec.{name} must be a {cls.__name__}")
        if (self.render.sun, self.render.model) != (self.lighting.sun, self.materials.model):
            render = dataclasses.replace(self.render, sun=self.lighting.sun, model=self.materials.model)
            object.__setattr__(self, "render", render)
        n_svbrdf = self.dataset.n_svbrdf
        if n_svbrdf and not self.materials.has_svbrdf_source:
            raise SpecError(
                "materials",
                "svbrdf_families",
                list(self.materials.svbrdf_families),
                f"at least one family (or a folder in materials.svbrdf_folders) when "
                f"dataset.svbrdf_fraction = {self.dataset.svbrdf_fraction:g} makes "
                f"{n_svbrdf} of {self.dataset.materials} materials SVBRDF",
            )
