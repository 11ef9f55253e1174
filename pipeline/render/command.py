"""`shaderball render`: one material under one sun and sky, to EXR (and PNG for people).

Every option is checked before anything is rendered or written; a bad value raises
ShaderballError naming the option, the value and the allowed range.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from geometry import build_shaderball, default_camera
from materials import UniformMaterial, load_deschaintre
from pipeline.errors import bad_value
from pipeline.fields import Checked, Choice, Float, Int, Optional, Reject, Triple, field, same_as
from pipeline.fields import Path as PathRule
from pipeline.image.tonemap import preview_srgb8
from pipeline.render.gbuffer import load_gbuffer
from pipeline.render.mitsuba_env import resolve_variant
from pipeline.render.raster import project_material
from pipeline.render.renderer import render_sample
from pipeline.render.settings import RenderSettings
from pipeline.store.atomic import write_bytes_atomic
from pipeline.store.exr import write_exr
from sky import Light
from sky.lighting import ELEVATION_RANGE, TURBIDITY_RANGE

SEED_RANGE = (0, 2**32 - 1)
#: Sun azimuth in degrees: any turn is one of these (a slip of a turn stays valid).
AZIMUTH_RANGE = (-360.0, 720.0)


def check_output(option: str, path: str, suffix: str) -> str:
    if not path.lower().endswith(suffix):
        raise bad_value(option, path, f"a file name ending in {suffix}")
    folder = os.path.dirname(os.path.abspath(path))
    existing = folder
    while not os.path.exists(existing):
        existing = os.path.dirname(existing)
    if not os.path.isdir(existing) or not os.access(existing, os.W_OK):
        raise bad_value(option, path, f"a path in a writable folder ({existing} is not writable)")
    if os.path.isdir(path):
        raise bad_value(option, path, "a file, not a folder")
    return path


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


class _Exists(PathRule):
    def check(self, value):
        value = super().check(value)
        if not os.path.exists(value):
            raise Reject()
        return value


@dataclass(frozen=True)
class RenderRequest(Checked):
    """Everything `shaderball render` needs, each option declared once (pipeline.fields);
    checked by :func:`check_request`."""

    FIELD_PREFIX: ClassVar[str] = "--"
    FIELD_LABELS: ClassVar[dict[str, str]] = {
        "elevation_deg": "--elevation",
        "azimuth_deg": "--azimuth",
    }

    diffuse: tuple[float, float, float] = field(
        (0.5, 0.5, 0.5), rule=_Colour(), doc="Uniform diffuse albedo, linear RGB."
    )
    specular: tuple[float, float, float] = field(
        (0.04, 0.04, 0.04),
        rule=_Colour(),
        doc="Uniform specular albedo (F0), linear RGB; 0.04 is a typical dielectric.",
    )
    roughness: float = field(0.3, rule=Float(0.0, 1.0), doc="Uniform roughness; GGX alpha = roughness^2.")
    normal: tuple[float, float, float] = field(
        (0.0, 0.0, 1.0), rule=_Normal(), doc="Uniform tangent-space normal (normalised)."
    )
    svbrdf: str | None = field(
        None,
        rule=Optional(_Exists("an existing PNG strip or folder of maps"), "unset (the uniform values)"),
        doc="Spatially varying material instead of the uniform values: a Deschaintre et al. "
        "PNG strip (photo|normal|diffuse|roughness|specular) or a folder of maps.",
    )
    svbrdf_colorspace: str = field(
        "raw",
        rule=Choice(("raw", "srgb")),
        doc="How 8-bit albedo maps of --svbrdf are decoded: raw (as Deschaintre's renderer) or sRGB.",
    )
    elevation_deg: float = field(
        45.0,
        rule=Float(*ELEVATION_RANGE),
        doc="Sun elevation above the horizon. Below ~2.4-7 degrees (by turbidity) the sun is raised to the "
        "floor where Mitsuba's sky is non-negative; the move is printed and recorded.",
        unit="degrees",
    )
    azimuth_deg: float = field(
        270.0,
        rule=Float(*AZIMUTH_RANGE),
        doc="Sun azimuth, counter-clockwise from +x seen from above: 0 lights the ball from the image's "
        "right, 90 from behind, 270 from the camera's side.",
        unit="degrees",
    )
    turbidity: float = field(3.0, rule=Float(*TURBIDITY_RANGE), doc="Atmospheric turbidity (1: very clear, 10: hazy).")
    spp: int = same_as(RenderSettings, "spp")
    resolution: int = same_as(RenderSettings, "resolution")
    max_depth: int = same_as(RenderSettings, "max_depth")
    seed: int = field(0, rule=Int(*SEED_RANGE), doc="Render seed.")
    sun: str = same_as(RenderSettings, "sun")
    model: str = same_as(RenderSettings, "model")
    variant: str = same_as(RenderSettings, "variant")
    out: str = field("render.exr", rule=PathRule("a file name ending in .exr"), doc="The EXR file written.")
    png: str | None = field(None, rule=Optional(PathRule("a file name ending in .png")), doc="The PNG written.")


@dataclass
class RenderSummary:
    out: str
    png: str | None
    stats: dict
    lighting: dict
    effects: dict
    extra: list = dataclasses.field(default_factory=list)

    def lines(self) -> list[str]:
        s, light = self.stats, self.lighting
        lines = [
            f"wrote {self.out}" + (f" and {self.png}" if self.png else ""),
            f"time {s['time_s']:.2f} s, {s['spp']} spp, seed {s['seed']}, attempts {s['attempts']}",
            f"min {s['min']:.4g}, max {s['max']:.4g}, mean {s['mean']:.4g}, "
            f"noise (RMS std. error) {s['noise_rmse']:.3g}",
            f"NaN {s['nan']}, Inf {s['inf']}, negative {s['negative']}"
            + (" -- FLAGGED: every attempt had bad pixels" if s["flagged"] else ""),
            "lighting policy: "
            + (
                "; ".join(f"{a['field']} {a['from']:g} -> {a['to']:g}" for a in light["actions"])
                if light.get("changed")
                else "nothing changed"
            )
            + (
                ", sun irradiance desaturated to non-negative RGB"
                if (light.get("emitter") or {}).get("sun_irradiance_adjusted")
                else ""
            ),
            f"effects: {', '.join(k for k, v in self.effects.items() if v) or 'none'}",
        ]
        return lines + self.extra


def load_material(req: RenderRequest):
    """The request's material as MaterialMaps (uniform values or an imported SVBRDF)."""

    if req.svbrdf:
        return load_deschaintre(req.svbrdf, req.svbrdf_colorspace)
    # check_request has refused bad values under their option names already.
    return UniformMaterial(req.diffuse, req.specular, req.roughness, req.normal).to_maps(1)


def render_settings(req: RenderRequest) -> RenderSettings:
    """The request's render settings (the variant as requested)."""
    return RenderSettings(
        resolution=req.resolution,
        spp=req.spp,
        max_depth=req.max_depth,
        variant=req.variant,
        sun=req.sun,
        model=req.model,
    )


def check_request(req: RenderRequest) -> None:
    """Check every field of ``req``; raise ShaderballError naming the option."""
    req.check_fields()
    Light(req.elevation_deg, req.azimuth_deg, req.turbidity)
    check_output("--out", req.out, ".exr")
    if req.png is not None:
        check_output("--png", req.png, ".png")


def render_to_files(req: RenderRequest) -> RenderSummary:
    """Check, render, then write the EXR (render + screen-space maps) and the optional PNG."""
    check_request(req)
    maps = load_material(req)  # may raise on a bad SVBRDF file: still nothing written
    maps.check()

    variant = resolve_variant(req.variant)  # chosen once, passed to all that follows
    ball, camera = build_shaderball(), default_camera()
    gbuffer = load_gbuffer(ball, camera, req.resolution, variant)
    settings = render_settings(req).resolved(variant)
    light = Light(req.elevation_deg, req.azimuth_deg, req.turbidity)
    result = render_sample(ball, camera, maps, light, settings, req.seed, mask=gbuffer.mask)
    screen = project_material(maps, gbuffer)
    meta = {
        "stats": result.stats,
        "lighting": result.lighting,
        "effects": result.effects.to_dict(),
        "request": {k: v for k, v in req.__dict__.items() if k not in ("out", "png")},
        # The network is told the light that was rendered: the policy's effective light.
        "lighting_vector": [float(x) for x in Light.from_dict(result.lighting["effective"]).lighting_vector()],
        "colorspace": "linear Rec.709 (sRGB primaries, D65)",
    }
    write_exr(
        req.out, {"render": result.image, **screen}, meta, half=("diffuse", "specular", "roughness", "normal", "mask")
    )
    if req.png:
        write_png(req.png, result.image, gbuffer.mask)
    return RenderSummary(
        req.out,
        req.png,
        result.stats,
        result.lighting,
        result.effects.to_dict(),
        extra=[f"material model: {req.model}"],
    )


def write_png(path: str, image: np.ndarray, mask: np.ndarray | None = None, exposure: float | None = None) -> None:
    import io

    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(preview_srgb8(image, exposure, mask)).save(buffer, format="PNG")
    write_bytes_atomic(path, buffer.getvalue())
