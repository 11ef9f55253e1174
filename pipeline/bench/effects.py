"""What the effects the build leaves out would cost: ``shaderball bench --effects``.

``shaderball bench --effects``
    Renders a few materials with each effect the build leaves out present and absent
    (:class:`pipeline.render.renderer.EffectPlan`) and reports the render time saved by each
    omission and whether the two images agree: bit-identical, equal to float rounding,
    or equal within noise by a per-pixel Z-test on the luminance variance of the
    ``moment`` integrator. The specular lobe of a zero specular albedo is measured too,
    to show why it is kept.

The BSDF builders (:func:`bitmap_bsdf`, :func:`flat_normal_map_bsdf`) make the scenes
with an omitted effect put back; tests/test_effects.py uses them too.
"""

from __future__ import annotations

import dataclasses
import statistics
from dataclasses import dataclass, field

import numpy as np

from geometry import build_shaderball, default_camera
from materials.maps import UniformMaterial, encode_normal_map
from pipeline.bench.compare import compare_renders, describe_comparison, render_moments
from pipeline.errors import ShaderballError
from pipeline.render import bsdf as mitsuba_bsdf
from pipeline.render.bsdf import bsdf_dict
from pipeline.render.mitsuba_env import load_mitsuba, resolve_variant
from pipeline.render.renderer import RenderSettings, plan_effects, scene_dict
from pipeline.render.scene import BALL_SHAPE_ID, bitmap_texture
from sky import Light


def bitmap_bsdf(maps, size: int, variant: str, lobes: dict | None = None) -> dict:
    """The material BSDF of a uniform ``maps`` with its values replicated in size x size bitmaps.

    What the build would render without the textured -> constant omission (no normal map:
    combine with :func:`flat_normal_map_bsdf` for that).
    """
    uniform = maps.uniform_values()
    if uniform is None:
        raise ShaderballError("bitmap_bsdf: the material is not uniform")
    replicated = uniform.to_maps(size)
    bsdf = mitsuba_bsdf.bsdf_dict(uniform.to_maps(1), lobes=lobes, variant=variant)
    if bsdf["type"] == "normalmap":
        bsdf = bsdf["bsdf"]
    bsdf = dict(bsdf)
    bsdf["diffuse"] = bitmap_texture(replicated.diffuse, variant=variant)
    bsdf["specular"] = bitmap_texture(replicated.specular, variant=variant)
    bsdf["roughness"] = bitmap_texture(replicated.roughness, variant=variant)
    return bsdf


def flat_normal_map_bsdf(bsdf: dict, size: int, variant: str) -> dict:
    """``bsdf`` inside Mitsuba's ``normalmap`` with a flat (0, 0, 1) size x size map."""
    flat = np.zeros((size, size, 3), np.float32)
    flat[..., 2] = 1.0
    return mitsuba_bsdf.normalmap_dict(bitmap_texture(encode_normal_map(flat), variant=variant), bsdf)


def with_material_bsdf(scene: dict, bsdf: dict) -> dict:
    """A copy of a scene dict of :func:`pipeline.render.renderer.scene_dict` with another material BSDF."""
    out = dict(scene)
    out[BALL_SHAPE_ID] = dict(scene[BALL_SHAPE_ID], bsdf=bsdf)
    return out


@dataclass
class EffectCase:
    omission: str
    material: str
    applied: bool  # does the build make this omission?
    wall_with: list[float]  # wall seconds of each timed render, with the effect
    wall_without: list[float]
    cpu_with: list[float]  # CPU seconds (all threads) of the same renders
    cpu_without: list[float]
    comparison: dict

    @staticmethod
    def _saved(with_: float, without: float) -> float:
        return 1.0 - without / with_ if with_ > 0 else 0.0

    @property
    def saved_wall(self) -> float:
        """Share of the wall time saved, best of the repeats of each (least disturbed by load)."""
        return self._saved(min(self.wall_with), min(self.wall_without))

    @property
    def saved_cpu(self) -> float:
        """Share of the CPU time saved, medians of the repeats."""
        return self._saved(statistics.median(self.cpu_with), statistics.median(self.cpu_without))

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "saved_wall": self.saved_wall, "saved_cpu": self.saved_cpu}


@dataclass
class EffectsBench:
    resolution: int
    spp: int
    repeats: int
    texture_size: int
    variant: str
    threads: int
    cases: list[EffectCase] = field(default_factory=list)

    def lines(self) -> list[str]:
        out = [
            f"effects benchmark: {self.resolution}x{self.resolution}, {self.spp} spp, {self.repeats} "
            f"alternating renders of each variant, {self.variant}, {self.threads} render threads; "
            f"textures {self.texture_size}x{self.texture_size}",
            "wall: best of the repeats; cpu: median CPU time of the process (all render threads)",
            f"{'omission':<36} {'material':<32} {'wall with/without':>18} {'saved':>6} "
            f"{'cpu with/without':>17} {'saved':>6}  images",
        ]
        for c in self.cases:
            name = c.omission + ("" if c.applied else " [not applied]")
            out.append(
                f"{name:<36} {c.material:<32} {min(c.wall_with):7.3f}/{min(c.wall_without):7.3f}s "
                f"{100 * c.saved_wall:5.1f}% {statistics.median(c.cpu_with):7.3f}/"
                f"{statistics.median(c.cpu_without):7.3f}s {100 * c.saved_cpu:5.1f}%  "
                f"{describe_comparison(c.comparison)}"
            )
        return out

    def to_dict(self) -> dict:
        return {
            **{k: v for k, v in dataclasses.asdict(self).items() if k != "cases"},
            "cases": [c.to_dict() for c in self.cases],
        }


def _effect_cases(texture_size: int, variant: str):
    """(omission, material label, applied by the build, scene with the effect, scene without).

    A scene is a function of ``base(maps, effects)`` (the build's scene dict for ``maps``,
    optionally with a forced :class:`pipeline.render.renderer.EffectPlan`).
    """

    dielectric = UniformMaterial((0.5, 0.3, 0.2), (0.04, 0.04, 0.04), 0.4).to_maps(1)
    metal = UniformMaterial((0.0, 0.0, 0.0), (0.95, 0.64, 0.54), 0.3).to_maps(1)
    no_specular = UniformMaterial((0.5, 0.5, 0.5), (0.0, 0.0, 0.0), 0.2).to_maps(1)

    def built(maps, **forced):
        effects = dataclasses.replace(plan_effects(maps), **forced) if forced else None
        return lambda base: base(maps, effects)

    def swapped(maps, make_bsdf):
        return lambda base: with_material_bsdf(base(maps, None), make_bsdf())

    return [
        (
            "textured -> constant",
            "uniform dielectric, r=0.4",
            True,
            swapped(dielectric, lambda: bitmap_bsdf(dielectric, texture_size, variant)),
            built(dielectric),
        ),
        (
            "normal map -> none",
            "uniform dielectric, flat normal",
            True,
            swapped(
                dielectric, lambda: flat_normal_map_bsdf(bsdf_dict(dielectric, variant=variant), texture_size, variant)
            ),
            built(dielectric),
        ),
        (
            "both -> constant, none",
            "uniform dielectric, flat normal",
            True,
            swapped(
                dielectric,
                lambda: flat_normal_map_bsdf(bitmap_bsdf(dielectric, texture_size, variant), texture_size, variant),
            ),
            built(dielectric),
        ),
        ("diffuse lobe -> none", "copper-like metal, d=0, r=0.3", True, built(metal, diffuse_lobe=True), built(metal)),
        (
            "specular lobe -> none",
            "dielectric s=0, d=0.5, r=0.2",
            False,
            built(no_specular),
            built(no_specular, specular_lobe=False),
        ),
    ]


def run_effects_bench(
    *,
    resolution: int,
    spp: int,
    repeats: int,
    texture_size: int = 256,
    seed: int = 1,
    variant: str = "auto",
    progress=None,
) -> EffectsBench:
    """Render time with and without each omission; see the module docstring. ``resolution``
    and ``spp`` are checked as the renderer's settings (pipeline.render.settings)."""

    variant = resolve_variant(variant)  # chosen once for the whole benchmark
    mi = load_mitsuba(variant)
    import drjit as dr

    settings = RenderSettings(resolution=resolution, spp=spp, variant=variant)
    ball, camera = build_shaderball(), default_camera()
    light = Light(35.0, 300.0, 3.0)  # sun from the camera's left, above: highlights and shading

    def base(maps, effects):
        return scene_dict(ball, camera, maps, light, settings, effects)[0]

    bench = EffectsBench(resolution, spp, repeats, texture_size, variant, dr.thread_count())
    for omission, label, applied, make_with, make_without in _effect_cases(texture_size, variant):
        if progress:
            progress(f"effects: {omission} ...")
        scene_with, scene_without = mi.load_dict(make_with(base)), mi.load_dict(make_without(base))
        first_with = render_moments(mi, scene_with, spp, seed)  # compiles; also the compared image
        first_without = render_moments(mi, scene_without, spp, seed)
        timed_with, timed_without = [], []
        for r in range(repeats):
            timed_with.append(render_moments(mi, scene_with, spp, seed + 1 + r))
            timed_without.append(render_moments(mi, scene_without, spp, seed + 1 + r))
        bench.cases.append(
            EffectCase(
                omission,
                label,
                applied,
                [t.seconds for t in timed_with],
                [t.seconds for t in timed_without],
                [t.cpu_seconds for t in timed_with],
                [t.cpu_seconds for t in timed_without],
                compare_renders(first_with, first_without),
            )
        )
    return bench
