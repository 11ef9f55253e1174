"""The parts that the commands rendering one material under one sun share: the material
(:class:`MaterialPart`) and the sun and sky (:class:`SunSkyPart`), each declared once and
nested in `shaderball render`'s and `shaderball infer`'s requests (pipeline.fields.part);
their options keep their own names (``--diffuse``, ``--elevation``).

The ranges are the domain's (``sky.lighting``, ``materials.maps``), declared there once.
"""

from __future__ import annotations

from dataclasses import dataclass

from materials import ALBEDO_RANGE, ROUGHNESS_RANGE, MaterialMaps, UniformMaterial, load_deschaintre
from pipeline.fields import Checked, field
from pipeline.fields.rules import Choice, Float, Optional, Path, Reject, Triple
from sky import Light
from sky.lighting import AZIMUTH_RANGE, ELEVATION_RANGE, TURBIDITY_RANGE


class _Normal(Triple):
    """A tangent-space direction: three numbers with Z > 0 (normalised when used)."""

    metavar = "X,Y,Z"

    def __init__(self):
        super().__init__(None, None, "a tangent-space direction X,Y,Z with Z > 0")

    def check(self, value):
        value = super().check(value)
        if value[2] <= 0:
            raise Reject()
        return value


class _Colour(Triple):
    metavar = "R,G,B"


@dataclass(frozen=True)
class MaterialPart(Checked):
    """One material: uniform values, or a spatially varying one read from files."""

    diffuse: tuple[float, float, float] = field(
        (0.5, 0.5, 0.5), rule=_Colour(*ALBEDO_RANGE), doc="Uniform diffuse albedo, linear RGB."
    )
    specular: tuple[float, float, float] = field(
        (0.04, 0.04, 0.04),
        rule=_Colour(*ALBEDO_RANGE),
        doc="Uniform specular albedo (F0), linear RGB; 0.04 is a typical dielectric.",
    )
    roughness: float = field(0.3, rule=Float(*ROUGHNESS_RANGE), doc="Uniform roughness; GGX alpha = roughness^2.")
    normal: tuple[float, float, float] = field(
        (0.0, 0.0, 1.0), rule=_Normal(), doc="Uniform tangent-space normal (normalised)."
    )
    svbrdf: str | None = field(
        None,
        rule=Optional(Path("an existing PNG strip or folder of maps", exists="any"), "unset (the uniform values)"),
        doc="Spatially varying material instead of the uniform values: a Deschaintre et al. "
        "PNG strip (photo|normal|diffuse|roughness|specular) or a folder of maps.",
    )
    svbrdf_colorspace: str = field(
        "raw",
        rule=Choice(("raw", "srgb")),
        doc="How 8-bit albedo maps of {svbrdf} are decoded: raw (as Deschaintre's renderer) or sRGB.",
    )

    def maps(self) -> MaterialMaps:
        """The material as checked maps (uniform values at 1x1, or the imported SVBRDF)."""
        if self.svbrdf:
            return load_deschaintre(self.svbrdf, self.svbrdf_colorspace).check()
        return UniformMaterial(self.diffuse, self.specular, self.roughness, self.normal).to_maps(1).check()


@dataclass(frozen=True)
class SunSkyPart(Checked):
    """The sun and sky: a Hosek-Wilkie sky given by the sun's direction and the turbidity."""

    elevation: float = field(
        45.0,
        rule=Float(*ELEVATION_RANGE),
        doc="Sun elevation above the horizon. Below ~2.4-7 degrees (by turbidity) the sun is raised to the "
        "floor where Mitsuba's sky is non-negative; the move is printed and recorded.",
        unit="degrees",
    )
    azimuth: float = field(
        270.0,
        rule=Float(*AZIMUTH_RANGE),
        doc="Sun azimuth, counter-clockwise from +x seen from above: 0 lights the ball from the image's "
        "right, 90 from behind, 270 from the camera's side.",
        unit="degrees",
    )
    turbidity: float = field(3.0, rule=Float(*TURBIDITY_RANGE), doc="Atmospheric turbidity (1: very clear, 10: hazy).")

    def light(self) -> Light:
        """The sun and sky asked for (before the low-sun policy)."""
        return Light(self.elevation, self.azimuth, self.turbidity)
