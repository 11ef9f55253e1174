"""`shaderball render`: one material under one sun and sky, to EXR (and PNG for people).

:class:`RenderRequest` declares every input once (``pipeline.fields``) and checks itself
when built: a bad value raises a :class:`pipeline.fields.FieldError` naming the field, the
value and what is allowed, before anything is rendered or written. Its material and its
sun and sky are parts (pipeline.render.parts) that `shaderball infer` nests too.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import os
import threading
import time
from dataclasses import dataclass

import numpy as np

from geometry import build_shaderball, default_camera
from pipeline.fields import Checked, field, flattened, part
from pipeline.fields.rules import Int, Optional
from pipeline.fields.rules import Path as PathRule
from pipeline.image.tonemap import preview_srgb8
from pipeline.render.gbuffer import load_gbuffer
from pipeline.render.mitsuba_env import resolve_variant
from pipeline.render.parts import MaterialPart, SunSkyPart
from pipeline.render.raster import project_material
from pipeline.render.renderer import render_sample, sample_stages
from pipeline.render.settings import RenderSettings
from pipeline.store.atomic import write_bytes_atomic
from pipeline.store.exr import write_exr
from sky import Light

SEED_RANGE = (0, 2**32 - 1)
#: How a render's EXR records the sun of its request: by the names of a Light's record.
RECORDED_AS = {"elevation": "elevation_deg", "azimuth": "azimuth_deg"}


def check_output(owner, name: str, path: str, suffix: str) -> str:
    """``path`` if it names a file ending in ``suffix`` in a folder that is (or can be made)
    writable; else ``owner``'s refusal of its field ``name``."""
    if not path.lower().endswith(suffix):
        raise owner.field_error(name, path, f"a file name ending in {suffix}")
    folder = os.path.dirname(os.path.abspath(path))
    existing = folder
    while not os.path.exists(existing):
        existing = os.path.dirname(existing)
    if not os.path.isdir(existing) or not os.access(existing, os.W_OK):
        raise owner.field_error(name, path, f"a path in a writable folder ({existing} is not writable)")
    if os.path.isdir(path):
        raise owner.field_error(name, path, "a file, not a folder")
    return path


@dataclass(frozen=True)
class RenderRequest(Checked):
    """Everything `shaderball render` needs, each input declared once (pipeline.fields);
    checked when built."""

    material: MaterialPart = part(MaterialPart, doc="The material rendered.")
    sun_sky: SunSkyPart = part(SunSkyPart, doc="The sun and sky it is lit by.")
    settings: RenderSettings = part(RenderSettings, doc="How it is path traced (a spec's [render] settings).")
    seed: int = field(0, rule=Int(*SEED_RANGE), doc="Render seed.")
    out: str = field(
        rule=PathRule("a file name ending in .exr"),
        doc="Output EXR file: layers render.R/G/B (float32) and the screen-space maps.",
        kw_only=True,
    )
    png: str | None = field(
        None,
        rule=Optional(PathRule("a file name ending in .png")),
        doc="Also write a tone-mapped PNG for people.",
        kw_only=True,
    )

    def check_cross(self) -> None:
        check_output(type(self), "out", self.out, ".exr")
        if self.png is not None:
            check_output(type(self), "png", self.png, ".png")

    def record(self) -> dict:
        """The request as a render's EXR records it: every field but the files written (its
        parts' fields too, as one flat table), the sun by a Light record's names
        (``elevation_deg``, ``azimuth_deg``)."""
        return {
            RECORDED_AS.get(name, name): getattr(functools.reduce(getattr, path, self), name)
            for name, (_, path) in flattened(type(self)).items()
            if name not in ("out", "png")
        }


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


class RenderProgress:
    """``progress(dict)`` of one render: ``what`` runs now, passes ``done`` of ``total`` (at most:
    an adaptive render may stop sooner), samples per pixel ``spp_done`` of ``spp``, ``elapsed_s``
    and ``eta_s`` (None until a pass is done; the first pass also compiles kernels, so the
    ETA falls after it). A re-render of bad pixels counts its passes again.

    While a pass renders it is said again every ``TICK_S`` seconds, from a thread of its own
    (Mitsuba renders without holding Python's lock): the largest pass comes first and is most
    of the time (128 of 150 spp), so without it a render would say nothing for most of its
    time. Calls never overlap."""

    TICK_S = 1.0

    def __init__(self, progress, settings: RenderSettings):
        self.progress = progress
        self.passes = [n for stage in sample_stages(settings) for n in stage]
        self.total = len(self.passes)
        self.spp, self.done, self.spp_done, self.rendered = settings.spp, 0, 0, 0
        self.what = ""
        self.started = time.perf_counter()
        self.lock = threading.Lock()

    def say(self, what: str) -> None:
        if self.progress is None:
            return
        with self.lock:
            self.what = what
            elapsed = time.perf_counter() - self.started
            eta = elapsed / self.rendered * (self.spp - self.spp_done) if self.rendered else None
            self.progress(
                {
                    "what": what,
                    "done": self.done,
                    "total": self.total,
                    "spp_done": self.spp_done,
                    "spp": self.spp,
                    "elapsed_s": elapsed,
                    "eta_s": eta,
                }
            )

    def _next(self) -> str:
        return f"rendering pass {self.done + 1} of {self.total} ({self.passes[self.done]} spp)"

    def on_pass(self, spp: int) -> None:
        """After each pass of :func:`pipeline.render.renderer.render_sample`."""
        if self.done == self.total:  # a re-render of bad pixels: its passes count again
            self.done, self.spp_done = 0, 0
        self.done += 1
        self.spp_done += spp
        self.rendered += spp
        self.say(self._next() if self.done < self.total else f"rendered {self.total} of {self.total} passes")

    @contextlib.contextmanager
    def rendering(self):
        """Say the pass that renders now every TICK_S seconds, until the block ends."""
        if self.progress is None:
            yield
            return
        stop = threading.Event()

        def tick():
            while not stop.wait(self.TICK_S):
                self.say(self.what)

        self.say(self._next())
        ticker = threading.Thread(target=tick, name="render-progress", daemon=True)
        ticker.start()
        try:
            yield
        finally:
            stop.set()
            ticker.join()


def render_to_files(req: RenderRequest, progress=None) -> RenderSummary:
    """Render, then write the EXR (render + screen-space maps) and the optional PNG; ``req``
    was checked when built. ``progress(dict)``: what runs, passes done, ETA (:class:`RenderProgress`)."""
    maps = req.material.maps()  # may raise on a bad SVBRDF file: still nothing written

    variant = resolve_variant(req.settings.variant)  # chosen once, passed to all that follows
    settings = req.settings.resolved(variant)
    show = RenderProgress(progress, settings)
    show.say(f"loading the shaderball, its G-buffer and the scene ({variant}; the first pass compiles kernels)")
    ball, camera = build_shaderball(), default_camera()
    gbuffer = load_gbuffer(ball, camera, settings.resolution, variant)
    with show.rendering():
        result = render_sample(
            ball, camera, maps, req.sun_sky.light(), settings, req.seed, mask=gbuffer.mask, on_pass=show.on_pass
        )
    show.say(f"writing {req.out}")
    screen = project_material(maps, gbuffer)
    meta = {
        "stats": result.stats,
        "lighting": result.lighting,
        "effects": result.effects.to_dict(),
        "request": req.record(),
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
        extra=[f"material model: {settings.model}"],
    )


def write_png(path: str, image: np.ndarray, mask: np.ndarray | None = None, exposure: float | None = None) -> None:
    import io

    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(preview_srgb8(image, exposure, mask)).save(buffer, format="PNG")
    write_bytes_atomic(path, buffer.getvalue())
