"""What the page asks for: one view (a material, a sun and sky, an exposure), checked.

Every value arrives as JSON from the page; each is checked here and a bad one is refused
with a :class:`RequestError` that names the field, the value and what is allowed (the
server answers it as a 4xx JSON error that the page shows). Nothing here reads a file.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from materials import SVBRDF_FAMILIES
from pipeline.errors import ShaderballError, short_repr
from sky import Light

#: Sun and sky ranges of the page's sliders (Mitsuba's sunsky takes turbidity 1..10; an
#: elevation below the low-sun floor is raised to it, as `shaderball render` does).
ELEVATION_RANGE = (0.0, 90.0)
AZIMUTH_RANGE = (0.0, 360.0)
TURBIDITY_RANGE = (1.0, 10.0)
#: A multiplier on linear radiance before the tone map (pipeline.image.tonemap).
EXPOSURE_RANGE = (0.0625, 64.0)
#: The normal map's uniform tilt, degrees from the surface normal.
TILT_RANGE = (0.0, 60.0)
SEED_RANGE = (0, 2**31 - 1)
#: The paper's "cloudiness" 0..3 and the turbidity each stands for.
CLOUDINESS_TURBIDITY = (2.0, 3.0, 6.0, 10.0)
MATERIAL_KINDS = ("uniform", "svbrdf", "dataset", "maps")
#: A client's id: the page makes one at random; it names a slot, never a file.
CLIENT_ID = re.compile(r"[A-Za-z0-9_-]{1,40}")
SAMPLE_ID = re.compile(r"m[0-9]{6,9}_l[0-9]{1,4}")


class RequestError(ShaderballError):
    """A request the server refuses: ``status`` is the HTTP status (4xx) it answers with."""

    def __init__(self, message: str, status: int = 400):
        super().__init__(message)
        self.status = status


def refused(field: str, value, allowed: str, status: int = 400) -> RequestError:
    return RequestError(f"{field}: {short_repr(value)} is not allowed; allowed: {allowed}", status)


def number(doc: dict, field: str, lo: float, hi: float, default: float | None = None) -> float:
    value = doc.get(field.rsplit(".", 1)[-1], default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise refused(field, value, f"a number in [{lo:g}, {hi:g}]")
    if not lo <= value <= hi:
        raise refused(field, value, f"a number in [{lo:g}, {hi:g}]")
    return float(value)


def colour(doc: dict, field: str, default) -> tuple[float, float, float]:
    value = doc.get(field.rsplit(".", 1)[-1], default)
    if (
        not isinstance(value, list)
        or len(value) != 3
        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
        or not all(0.0 <= v <= 1.0 for v in value)
    ):
        raise refused(field, value, "three numbers in [0, 1] (linear RGB)")
    return tuple(float(v) for v in value)


def client_id(value) -> str:
    if not isinstance(value, str) or not CLIENT_ID.fullmatch(value):
        raise refused("client", value, "1 to 40 letters, digits, '-' or '_'")
    return value


@dataclass(frozen=True)
class UniformChoice:
    diffuse: tuple[float, float, float]
    specular: float  # a dielectric's F0 (grey); a metal's specular colour is ``diffuse``
    roughness: float
    metal: bool
    tilt_deg: float


@dataclass(frozen=True)
class SvbrdfChoice:
    family: str
    seed: int


@dataclass(frozen=True)
class DatasetChoice:
    sample: str


@dataclass(frozen=True)
class MapsChoice:
    """The client's uploaded (or painted) maps; a map not uploaded takes the uniform defaults."""


@dataclass(frozen=True)
class View:
    material: UniformChoice | SvbrdfChoice | DatasetChoice | MapsChoice
    light: Light
    exposure: float

    def material_key(self) -> tuple:
        return (type(self.material).__name__, *self.material.__dict__.values())


def parse_material(doc) -> UniformChoice | SvbrdfChoice | DatasetChoice | MapsChoice:
    if not isinstance(doc, dict):
        raise refused("material", doc, "an object with a kind: " + ", ".join(MATERIAL_KINDS))
    kind = doc.get("kind")
    if kind == "uniform":
        metal = doc.get("metal", False)
        if not isinstance(metal, bool):
            raise refused("material.metal", metal, "true or false")
        return UniformChoice(
            diffuse=colour(doc, "material.diffuse", [0.5, 0.5, 0.5]),
            specular=number(doc, "material.specular", 0.0, 1.0, 0.04),
            roughness=number(doc, "material.roughness", 0.0, 1.0, 0.3),
            metal=metal,
            tilt_deg=number(doc, "material.tilt_deg", *TILT_RANGE, 0.0),
        )
    if kind == "svbrdf":
        family = doc.get("family")
        if family not in SVBRDF_FAMILIES:
            raise refused("material.family", family, ", ".join(SVBRDF_FAMILIES))
        seed = doc.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int) or not SEED_RANGE[0] <= seed <= SEED_RANGE[1]:
            raise refused("material.seed", seed, f"an integer in [{SEED_RANGE[0]}, {SEED_RANGE[1]}]")
        return SvbrdfChoice(family, seed)
    if kind == "dataset":
        sample = doc.get("sample")
        if not isinstance(sample, str) or not SAMPLE_ID.fullmatch(sample):
            raise refused("material.sample", sample, "a sample id of the dataset, such as m000000_l0")
        return DatasetChoice(sample)
    if kind == "maps":
        return MapsChoice()
    raise refused("material.kind", kind, ", ".join(MATERIAL_KINDS))


def parse_light(doc) -> Light:
    if not isinstance(doc, dict):
        raise refused("light", doc, "an object with elevation_deg, azimuth_deg, turbidity")
    return Light(
        number(doc, "light.elevation_deg", *ELEVATION_RANGE, 45.0),
        number(doc, "light.azimuth_deg", *AZIMUTH_RANGE, 270.0),
        number(doc, "light.turbidity", *TURBIDITY_RANGE, 3.0),
    )


def parse_view(doc) -> tuple[str, View]:
    """(client id, view) of the JSON document the page posts to /api/view."""
    if not isinstance(doc, dict):
        raise refused("body", doc, "a JSON object with client, material, light, exposure")
    client = client_id(doc.get("client"))
    exposure = number(doc, "exposure", *EXPOSURE_RANGE, 4.0)
    return client, View(parse_material(doc.get("material")), parse_light(doc.get("light")), exposure)
