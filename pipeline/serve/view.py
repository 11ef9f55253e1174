"""What the page asks for: one view (a material, a sun and sky, an exposure), checked.

Every value arrives as JSON from the page. Each part of the document is a checked request
(:class:`pipeline.fields.Checked`) whose fields are named as the JSON names them, with the
rules built from the domain's ranges (``sky.lighting``, ``materials``), declared there once.
A bad value is refused with a :class:`pipeline.fields.FieldError` naming the field by its
own name; :func:`api_error` words it as the document spells it (``light.azimuth_deg``), and
the server answers it as a 4xx JSON error that the page shows. Nothing here reads a file.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import ClassVar

from materials import ALBEDO_RANGE, ROUGHNESS_RANGE, SVBRDF_FAMILIES
from pipeline.errors import ShaderballError
from pipeline.fields import Checked, FieldError, declared, default_of, field
from pipeline.fields.rules import MISSING, Bool, Choice, Float, Int, Reject, Rule, Text, Triple
from sky import Light
from sky.lighting import AZIMUTH_TURN, ELEVATION_RANGE, TURBIDITY_RANGE

#: A multiplier on linear radiance before the tone map (pipeline.image.tonemap).
EXPOSURE_RANGE = (0.0625, 64.0)
#: The normal map's uniform tilt, degrees from the surface normal.
TILT_RANGE = (0.0, 60.0)
SEED_RANGE = (0, 2**31 - 1)
#: The paper's "cloudiness" 0..3 and the turbidity each stands for.
CLOUDINESS_TURBIDITY = (2.0, 3.0, 6.0, 10.0)
MATERIAL_KINDS = ("uniform", "svbrdf", "dataset", "maps")
#: What an 8-bit albedo PNG upload (diffuse, specular) means: "linear" (value / 255 is the
#: albedo, as docs/serve.md says) or "srgb". The page paints in sRGB and converts its
#: canvases to this before uploading, so the painted colour is the colour rendered.
ALBEDO_PNG = "linear"
#: The maps a page uploads (texture space).
MAP_NAMES = ("diffuse", "specular", "roughness", "normal")
#: A client's id: the page makes one at random; it names a slot, never a file.
CLIENT_ID = re.compile(r"[A-Za-z0-9_-]{1,40}")
SAMPLE_ID = re.compile(r"m[0-9]{6,9}_l[0-9]{1,4}")


class RequestError(ShaderballError):
    """A request the server refuses that is no field's value (a body that is not JSON, a
    file that is not an image): ``status`` is the HTTP status (4xx) it answers with."""

    def __init__(self, message: str, status: int = 400):
        super().__init__(message)
        self.status = status


def with_status(error: FieldError, status: int) -> FieldError:
    """``error``, answered with HTTP ``status`` rather than 400 (a sample id well formed but
    not in the dataset: 404; an upload too large: 413)."""
    error.status = status
    return error


# --------------------------------------------------------------------------- rules


class _Number(Float):
    """A JSON number in [lo, hi]: an integer too large for a float (``1e400`` is inf, but
    ``1`` followed by 400 zeros is an int) is refused like any other, not an OverflowError."""

    def check(self, value):
        try:
            return super().check(value)
        except OverflowError:
            raise Reject() from None


class _Colour(Triple):
    def check(self, value):
        try:
            return super().check(value)
        except OverflowError:
            raise Reject() from None


CLIENT = Text(CLIENT_ID.pattern, "1 to 40 letters, digits, '-' or '_'")


class _Object(Rule):
    """A JSON object (its own fields are checked by the part it is)."""

    def __init__(self, allowed: str):
        self.allowed = allowed

    def check(self, value):
        if not isinstance(value, dict):
            raise Reject()
        return value


# --------------------------------------------------------------------------- parts


class Part(Checked):
    """A part of a JSON document, checked when built. ``SPELLED``: how the document spells
    its fields (``"light."`` + name); :func:`api_error` reads it."""

    SPELLED: ClassVar[str] = ""
    #: The HTTP status of a refusal of a field, where not 400.
    STATUS: ClassVar[dict[str, int]] = {}

    @classmethod
    def from_doc(cls, doc: dict):
        """The part of ``doc`` (a dict): a field it leaves out takes its default; a required
        one left out is refused as ``none``. Keys that are no field are ignored."""
        values = {}
        for name, f in declared(cls).items():
            default = default_of(f)
            values[name] = doc.get(name, None if default is MISSING else default)
        return cls(**values)


@dataclass(frozen=True)
class LightChoice(Part):
    """``light``: the sun and sky (the ranges are sky's; the azimuth one turn, as the slider's)."""

    SPELLED: ClassVar[str] = "light."

    elevation_deg: float = field(
        45.0, rule=_Number(*ELEVATION_RANGE), doc="Sun elevation above the horizon.", unit="degrees"
    )
    azimuth_deg: float = field(
        270.0, rule=_Number(*AZIMUTH_TURN), doc="Sun azimuth, counter-clockwise from +x.", unit="degrees"
    )
    turbidity: float = field(3.0, rule=_Number(*TURBIDITY_RANGE), doc="Atmospheric turbidity.")

    def light(self) -> Light:
        return Light(self.elevation_deg, self.azimuth_deg, self.turbidity)


@dataclass(frozen=True)
class MaterialKind(Part):
    """``material.kind``: which of the material parts follows."""

    SPELLED: ClassVar[str] = "material."

    kind: str = field(rule=Choice(MATERIAL_KINDS), doc="What the material is made from.")


@dataclass(frozen=True)
class UniformChoice(Part):
    SPELLED: ClassVar[str] = "material."

    diffuse: tuple[float, float, float] = field(
        (0.5, 0.5, 0.5),
        rule=_Colour(*ALBEDO_RANGE, allowed="three numbers in [{:g}, {:g}] (linear RGB)".format(*ALBEDO_RANGE)),
        doc="Diffuse albedo, linear RGB; a metal's specular albedo.",
    )
    #: A dielectric's F0 (grey); a metal's specular colour is ``diffuse``.
    specular: float = field(0.04, rule=_Number(*ALBEDO_RANGE), doc="A dielectric's specular albedo (grey).")
    roughness: float = field(0.3, rule=_Number(*ROUGHNESS_RANGE), doc="Roughness; GGX alpha = roughness^2.")
    metal: bool = field(False, rule=Bool(), doc="A metal: no diffuse lobe, the colour is the specular albedo.")
    tilt_deg: float = field(0.0, rule=_Number(*TILT_RANGE), doc="The normal's uniform tilt.", unit="degrees")


@dataclass(frozen=True)
class SvbrdfChoice(Part):
    SPELLED: ClassVar[str] = "material."

    family: str = field(rule=Choice(SVBRDF_FAMILIES), doc="A procedural SVBRDF family.")
    seed: int = field(0, rule=Int(*SEED_RANGE), doc="The family's seed.")


@dataclass(frozen=True)
class DatasetChoice(Part):
    SPELLED: ClassVar[str] = "material."

    sample: str = field(
        rule=Text(SAMPLE_ID.pattern, "a sample id of the dataset, such as m000000_l0"),
        doc="A sample of the dataset served.",
    )


@dataclass(frozen=True)
class MapsChoice(Part):
    """The client's uploaded (or painted) maps; a map not uploaded takes the uniform defaults."""

    SPELLED: ClassVar[str] = "material."


MATERIAL_PARTS = {"uniform": UniformChoice, "svbrdf": SvbrdfChoice, "dataset": DatasetChoice, "maps": MapsChoice}


@dataclass(frozen=True)
class ViewRequest(Part):
    """The document the page posts to /api/view."""

    client: str = field(rule=CLIENT, doc="The page's id.")
    material: dict = field(
        rule=_Object("an object with a kind: " + ", ".join(MATERIAL_KINDS)), doc="The material (its own part)."
    )
    light: dict = field(
        rule=_Object("an object with elevation_deg, azimuth_deg, turbidity"), doc="The sun and sky (its own part)."
    )
    exposure: float = field(4.0, rule=_Number(*EXPOSURE_RANGE), doc="Multiplier on radiance before the tone map.")
    fresh: bool = field(
        False, rule=Bool(), doc="The page's first view since it loaded: what the server held for the client is dropped."
    )


@dataclass(frozen=True)
class FrameRequest(Part):
    """The query of /api/frame."""

    client: str = field(rule=CLIENT, doc="The page's id.")
    since: str = field(
        "0", rule=Text(r"[0-9]{1,12}", "a non-negative integer (the last version seen)"), doc="The last version seen."
    )


@dataclass(frozen=True)
class UploadRequest(Part):
    """The query of /api/upload (the map's bytes are the body)."""

    client: str = field(rule=CLIENT, doc="The page's id.")
    #: An unknown map is not found (404): the query names it as a path names a page.
    STATUS: ClassVar[dict[str, int]] = {"map": 404}

    map: str = field(rule=Choice(MAP_NAMES), doc="Which map the body is.")


# --------------------------------------------------------------------------- the view


@dataclass(frozen=True)
class View:
    material: UniformChoice | SvbrdfChoice | DatasetChoice | MapsChoice
    light: Light
    exposure: float

    def material_key(self) -> tuple:
        return (type(self.material).__name__, *self.material.__dict__.values())


def parse_material(doc: dict) -> UniformChoice | SvbrdfChoice | DatasetChoice | MapsChoice:
    """The material part of a view (``doc`` is a dict: :class:`ViewRequest` checked it)."""
    kind = MaterialKind.from_doc(doc).kind
    return MATERIAL_PARTS[kind].from_doc(doc)


def parse_view(doc) -> tuple[str, View]:
    """(client id, view) of the JSON document the page posts to /api/view."""
    if not isinstance(doc, dict):
        raise FieldError("body", doc, "a JSON object with client, material, light, exposure", name="")
    request = ViewRequest.from_doc(doc)
    material = parse_material(request.material)
    light = LightChoice.from_doc(request.light).light()
    return request.client, View(material, light, request.exposure)


def is_fresh(doc: dict) -> bool:
    """``fresh`` of a view document :func:`parse_view` took: a reloaded page's first view."""
    return ViewRequest.from_doc(doc).fresh


def api_error(error: FieldError) -> FieldError:
    """``error`` worded as the JSON document spells its field: ``light.azimuth_deg``."""
    prefix = getattr(error.owner, "SPELLED", "")
    return error.labelled(lambda name: prefix + name)


def api_status(error: FieldError) -> int:
    """The HTTP status (4xx) ``error`` is answered with: its own, its field's, or 400."""
    return getattr(error, "status", None) or getattr(error.owner, "STATUS", {}).get(error.name, 400)


def api_ranges() -> dict[str, list]:
    """Every number the page sends, by its JSON name: [lo, hi] as the API checks it (the page's
    sliders read these from /api/info)."""
    ranges = {}
    for part in (LightChoice, UniformChoice, SvbrdfChoice, ViewRequest):
        for name, f in declared(part).items():
            rule = f.metadata["rule"]
            if isinstance(rule, (Float, Int)):
                ranges[name] = [rule.lo, rule.hi]
    return ranges


def api_defaults() -> dict[str, object]:
    """What each field of the page's light and uniform material is when the page leaves it out."""
    defaults = {}
    for part in (LightChoice, UniformChoice, SvbrdfChoice, ViewRequest):
        for name, f in declared(part).items():
            value = default_of(f)
            if value is not MISSING:
                defaults[name] = list(value) if isinstance(value, tuple) else value
    return defaults
