"""`shaderball render`: one material under one sun and sky, to EXR (and PNG for people).

Every option is checked before anything is rendered or written; a bad value raises
ShaderballError naming the option, the value and the allowed range.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from geometry import build_shaderball, default_camera
from materials import UniformMaterial, load_deschaintre
from pipeline.errors import bad_value, check_int
from pipeline.fields import FieldError
from pipeline.image.tonemap import preview_srgb8
from pipeline.render.gbuffer import load_gbuffer
from pipeline.render.mitsuba_env import VARIANT_CHOICES, resolve_variant
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


def parse_triple(option: str, text: str, lo: float | None = 0.0, hi: float | None = 1.0) -> tuple[float, ...]:
    """'R,G,B' -> three finite floats within [lo, hi] (None: unbounded)."""
    allowed = "three comma-separated numbers" + (f" in [{lo}, {hi}]" if lo is not None else "")
    try:
        values = tuple(float(x) for x in str(text).split(","))
    except ValueError:
        raise bad_value(option, text, allowed) from None
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise bad_value(option, text, allowed)
    if lo is not None and not all(lo <= v <= hi for v in values):
        raise bad_value(option, text, allowed)
    return values


def check_number(option: str, value, lo: float, hi: float, unit: str = "") -> float:
    if value is None or not math.isfinite(float(value)) or not lo <= float(value) <= hi:
        raise bad_value(option, value, f"a number in [{lo}, {hi}]{unit}")
    return float(value)


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


@dataclass(frozen=True)
class RenderRequest:
    """Everything `shaderball render` needs, already checked."""

    diffuse: tuple[float, float, float] = (0.5, 0.5, 0.5)
    specular: tuple[float, float, float] = (0.04, 0.04, 0.04)
    roughness: float = 0.3
    normal: tuple[float, float, float] = (0.0, 0.0, 1.0)
    svbrdf: str | None = None
    svbrdf_colorspace: str = "raw"
    elevation_deg: float = 45.0
    azimuth_deg: float = 270.0
    turbidity: float = 3.0
    spp: int = RenderSettings.spp
    resolution: int = RenderSettings.resolution
    max_depth: int = RenderSettings.max_depth
    seed: int = 0
    sun: str = RenderSettings.sun
    model: str = RenderSettings.model
    variant: str = RenderSettings.variant
    out: str = "render.exr"
    png: str | None = None


@dataclass
class RenderSummary:
    out: str
    png: str | None
    stats: dict
    lighting: dict
    effects: dict
    extra: list = field(default_factory=list)

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

    parse_triple("--diffuse", ",".join(map(str, req.diffuse)))
    parse_triple("--specular", ",".join(map(str, req.specular)))
    check_number("--roughness", req.roughness, 0.0, 1.0)
    normal = parse_triple("--normal", ",".join(map(str, req.normal)), None, None)
    if normal[2] <= 0 or np.linalg.norm(normal) == 0:
        raise bad_value("--normal", ",".join(map(str, req.normal)), "a tangent-space direction X,Y,Z with Z > 0")
    if req.svbrdf is not None and not os.path.exists(req.svbrdf):
        raise bad_value("--svbrdf", req.svbrdf, "an existing PNG strip or folder of maps")
    check_number("--elevation", req.elevation_deg, *ELEVATION_RANGE, " degrees")
    check_number("--azimuth", req.azimuth_deg, *AZIMUTH_RANGE, " degrees")
    check_number("--turbidity", req.turbidity, *TURBIDITY_RANGE)
    check_int("--seed", req.seed, *SEED_RANGE)
    if req.variant not in VARIANT_CHOICES:
        raise bad_value("--variant", req.variant, ", ".join(VARIANT_CHOICES))
    try:
        render_settings(req)
    except FieldError as exc:  # named as the command's option
        raise FieldError("--" + exc.name.replace("_", "-"), exc.value, exc.allowed, what=exc.what) from None
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
