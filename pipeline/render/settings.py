"""How a sample is rendered: the spec's ``[render]`` section and the renderer's settings,
one checked dataclass.

:class:`RenderSettings` declares each field once (``pipeline.fields``): its rule, default,
unit and help. The spec reads it as its ``[render]`` section (docs/spec.md is generated
from these declarations), the renderer takes it as it is, and the commands' options
(``render``, ``bench``, ``study``) are generated from it. Two fields are not in the spec's
``[render]`` table: ``sun`` and ``model`` come from the spec's ``lighting.sun`` and
``materials.model`` (``pipeline.dataset.spec.DatasetSpec`` fills them in).

``variant`` is the requested Mitsuba backend in a spec (``auto``, ``llvm``, ...); a build or
command resolves it once (``pipeline.render.mitsuba_env.resolve_variant``) and renders with
:meth:`RenderSettings.resolved`, whose ``variant`` is the full name.

Pure: no Mitsuba here.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

from materials.brdf_ref import DEFAULT_MODEL, MODELS
from pipeline.fields import Checked, field
from pipeline.fields.rules import Choice, Float, Int
from pipeline.render.limits import (
    CLAMP_RANGE,
    DEFAULT_RR_DEPTH,
    INTEGRATORS,
    MAX_DEPTH_RANGE,
    RESOLUTION_RANGE,
    RR_DEPTH_RANGE,
    SAMPLERS,
    SPP_RANGE,
    TARGET_ERROR_RANGE,
    launch_limit_text,
)
from pipeline.render.mitsuba_env import SHORT_VARIANTS, VARIANT_CHOICES
from sky.emitter import SUN_MODES

#: What ``variant`` accepts: a request (auto, llvm, cuda, scalar) or the full name one resolves to.
VARIANTS: tuple[str, ...] = VARIANT_CHOICES + tuple(SHORT_VARIANTS.values())


@dataclass(frozen=True)
class RenderSettings(Checked):
    """[render]: how each target image is path traced."""

    SECTION: ClassVar[str] = "render"
    FIELD_PREFIX: ClassVar[str] = "render."

    resolution: int = field(
        400,
        rule=Int(*RESOLUTION_RANGE),
        doc="Width and height of renders and screen-space maps; the paper: 400.",
        unit="pixels",
    )
    spp: int = field(
        150,
        rule=Int(*SPP_RANGE),
        doc="Samples per pixel of each render; the paper: 150. A render of more than "
        f"{launch_limit_text()} samples (resolution^2 x spp, Mitsuba's most in one launch) is "
        "rendered in several launches, averaged.",
        unit="samples per pixel",
    )
    max_depth: int = field(
        8,
        rule=Int(*MAX_DEPTH_RANGE, also=(-1,), also_text="-1 (unlimited, Russian roulette ends paths)"),
        doc="Longest light path, in Mitsuba's convention (1: emitters "
        "seen directly only, 2: direct lighting, ...). -1: no limit.",
        unit="path vertices",
    )
    integrator: str = field("path", rule=Choice(INTEGRATORS), doc="Mitsuba integrator.")
    variant: str = field(
        "auto",
        rule=Choice(VARIANTS),
        doc="Mitsuba backend: auto (cuda if a GPU is usable, else llvm), "
        + ", ".join(f"{k} ({v})" for k, v in SHORT_VARIANTS.items())
        + ", or one of those full names. Renders are reproducible for one backend and machine only.",
    )
    sampler: str = field(
        "independent",
        rule=Choice(SAMPLERS),
        doc="Mitsuba sampler: independent (the paper), stratified, multijitter, orthogonal, "
        "ldsampler. Mitsuba rounds some spp (stratified to a square, orthogonal to a prime "
        "squared, ldsampler to a power-of-two square): each render records the spp used "
        "(docs/accuracy.md compares them). Byte-reproducible with several render threads "
        "only when every power-of-two pass stays a power of two after rounding (e.g. "
        "multijitter or stratified at 64).",
    )
    rr_depth: int = field(
        DEFAULT_RR_DEPTH,
        rule=Int(*RR_DEPTH_RANGE),
        doc="Path depth at which Russian roulette starts (Mitsuba's default); at or above max_depth there is none.",
        unit="path vertices",
    )
    clamp: float = field(
        0.0,
        rule=Float(*CLAMP_RANGE),
        doc="Firefly clamp: each camera path's radiance is scaled down to this luminance "
        "when brighter (pipeline.render.clamp); 0: off. Biased: it removes real light "
        "(docs/accuracy.md measures how much).",
        unit="radiance (W m^-2 sr^-1)",
    )
    target_error: float = field(
        0.0,
        rule=Float(*TARGET_ERROR_RANGE),
        doc="Adaptive rendering: render power-of-two passes (16 spp, then doubling) until "
        "the moment integrator's estimate of the relative RMS error of the luminance on "
        "the ball, sqrt(mean(var / (Y^2 + 0.01))), the square root of the relMSE the "
        "study ranks by, is at most this, or spp (then the cap) is reached; each "
        "render records the spp used. 0: off, every render takes spp.",
    )
    sun: str = field(
        "split",
        rule=Choice(SUN_MODES),
        doc="How the sun is given to Mitsuba: split, a delta sun beside a sky-only sunsky (the measured "
        "default, docs/sky.md), or sunsky, the sun disk inside sunsky (the spec's lighting.sun).",
        in_file=False,
    )
    model: str = field(
        DEFAULT_MODEL,
        rule=Choice(MODELS),
        doc="The BRDF every material is rendered with: shaderball (GGX as published, energy-conserving) or "
        "deschaintre2018 (Deschaintre et al.'s code, with its floors on GGX D and Smith G1; darker below "
        "roughness 0.178; docs/materials.md). The spec's materials.model.",
        in_file=False,
    )

    def resolved(self, variant: str) -> RenderSettings:
        """These settings rendering with ``variant``, the full name resolved once."""
        return dataclasses.replace(self, variant=variant)

    @property
    def adaptive(self) -> bool:
        return self.target_error > 0
