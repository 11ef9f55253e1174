"""What the page asks for: one view (a material, an object, a light, an exposure), checked.

Every value arrives as JSON from the page. Each part of the document is a checked request
(:class:`pipeline.fields.Checked`) whose fields are named as the JSON names them, with the
rules built from the domain's ranges (``sky.lighting``, ``materials``), declared there once.
A bad value is refused with a :class:`pipeline.fields.FieldError` naming the field by its
own name; :func:`api_error` words it as the document spells it (``light.azimuth_deg``), and
the server answers it as a 4xx JSON error that the page shows. Nothing here reads a file:
an object or an environment map is named by an id the server offers
(:class:`pipeline.serve.scenes.Scenes`, opened at start), never by a path.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import ClassVar

from materials import ALBEDO_RANGE, ROUGHNESS_RANGE, SVBRDF_FAMILIES
from pipeline.errors import ShaderballError
from pipeline.fields import Checked, FieldError, declared, default_of, field
from pipeline.fields.rules import MISSING, Bool, Choice, Float, Int, Reject, Rule, Text, Triple
from pipeline.serve.scenes import DEFAULT_OBJECT, ObjectChoice, Scenes
from sky import Light
from sky.environment import ROTATION_RANGE, SCALE_RANGE
from sky.lighting import AZIMUTH_TURN, ELEVATION_RANGE, TURBIDITY_RANGE

#: A multiplier on linear radiance before the tone map (pipeline.image.tonemap).
EXPOSURE_RANGE = (0.0625, 64.0)
#: The normal map's uniform tilt, degrees from the surface normal.
TILT_RANGE = (0.0, 60.0)
SEED_RANGE = (0, 2**31 - 1)
#: The paper's "cloudiness" 0..3 and the turbidity each stands for.
CLOUDINESS_TURBIDITY = (2.0, 3.0, 6.0, 10.0)
MATERIAL_KINDS = ("uniform", "svbrdf", "dataset", "maps")
#: What lights a view: the paper's sun and sky, or an HDR environment map the server offers.
LIGHT_SOURCES = ("sun_sky", "environment")
#: An object's or a map's id as /api/info lists it (a built-in name, a file's base name).
SCENE_ID = r"[^\x00-\x1f/\\]{1,255}"
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
    source: str = field("sun_sky", rule=Choice(LIGHT_SOURCES), doc="The sun and sky, or an environment map.")
    environment: str = field(
        "",
        rule=Text(f"|{SCENE_ID}", "an environment map's id as /api/info lists it"),
        doc="The map (source environment).",
    )

    def light(self, scenes: Scenes | None = None):
        """A ``sky.Light``, or the chosen map's ``EnvironmentLight`` (``scenes``: what the
        server offers; the map's rotation and intensity are an :class:`EnvironmentChoiceDoc`)."""
        if self.source == "sun_sky":
            return Light(self.elevation_deg, self.azimuth_deg, self.turbidity)
        offered = scenes.environments if scenes is not None else {}
        if not offered:
            raise type(self).field_error(
                "source", self.source, "sun_sky (start `shaderball serve --environment PATH` to offer maps)"
            )
        choice = offered.get(self.environment)
        if choice is None:
            raise with_status(
                type(self).field_error("environment", self.environment, "one of " + ", ".join(offered)), 404
            )
        return choice


@dataclass(frozen=True)
class EnvironmentChoiceDoc(Part):
    """``light``'s turn and brightness of an environment map (ranges: sky.environment)."""

    SPELLED: ClassVar[str] = "light."

    rotation_deg: float = field(
        0.0, rule=_Number(*ROTATION_RANGE), doc="The map's turn about +z, counter-clockwise from above.", unit="degrees"
    )
    intensity: float = field(1.0, rule=_Number(*SCALE_RANGE), doc="Multiplier on the map's radiance.")


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
    object: str = field(DEFAULT_OBJECT, rule=Text(SCENE_ID, "an object's id as /api/info lists it"), doc="The object.")
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


#: The object of a view parsed without the server's offer (the page's default): the shaderball.
DEFAULT_CHOICE = ObjectChoice(DEFAULT_OBJECT, DEFAULT_OBJECT, "built-in")


@dataclass(frozen=True)
class View:
    material: UniformChoice | SvbrdfChoice | DatasetChoice | MapsChoice
    light: object  # sky.Light or sky.environment.EnvironmentLight
    exposure: float
    object: ObjectChoice = DEFAULT_CHOICE

    def material_key(self) -> tuple:
        return (type(self.material).__name__, *self.material.__dict__.values())


def parse_material(doc: dict) -> UniformChoice | SvbrdfChoice | DatasetChoice | MapsChoice:
    """The material part of a view (``doc`` is a dict: :class:`ViewRequest` checked it)."""
    kind = MaterialKind.from_doc(doc).kind
    return MATERIAL_PARTS[kind].from_doc(doc)


def parse_view(doc, scenes: Scenes | None = None) -> tuple[str, View]:
    """(client id, view) of the JSON document the page posts to /api/view; ``scenes``: the
    objects and maps the server offers (None: the shaderball under the sun and sky only)."""
    if not isinstance(doc, dict):
        raise FieldError("body", doc, "a JSON object with client, material, light, exposure", name="")
    request = ViewRequest.from_doc(doc)
    material = parse_material(request.material)
    chosen = LightChoice.from_doc(request.light).light(scenes)
    if not isinstance(chosen, Light):  # an EnvironmentChoice: its turn and brightness
        turn = EnvironmentChoiceDoc.from_doc(request.light)
        chosen = chosen.light(turn.rotation_deg, turn.intensity)
    objects = scenes.objects if scenes is not None else {DEFAULT_OBJECT: DEFAULT_CHOICE}
    if request.object not in objects:
        raise with_status(ViewRequest.field_error("object", request.object, "one of " + ", ".join(objects)), 404)
    return request.client, View(material, chosen, request.exposure, objects[request.object])


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


def environment_ranges() -> dict[str, dict]:
    """The environment map's numbers, as :func:`api_ranges` and :func:`api_defaults` give the
    others: {"ranges": {name: [lo, hi]}, "defaults": {name: value}}."""
    fields = declared(EnvironmentChoiceDoc).items()
    return {
        "ranges": {name: [f.metadata["rule"].lo, f.metadata["rule"].hi] for name, f in fields},
        "defaults": {name: default_of(f) for name, f in fields},
    }


def api_defaults() -> dict[str, object]:
    """What each field of the page's light and uniform material is when the page leaves it out."""
    defaults = {}
    for part in (LightChoice, UniformChoice, SvbrdfChoice, ViewRequest):
        for name, f in declared(part).items():
            value = default_of(f)
            if value is not MISSING:
                defaults[name] = list(value) if isinstance(value, tuple) else value
    return defaults
