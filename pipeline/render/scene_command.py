"""`shaderball scene`: write the shaderball mesh, its G-buffer and a preview picture.

The preview puts two panels side by side: the shaderball path-traced with a checker
texture through the UV atlas (diffuse, constant sky plus a directional light), and its
material mask (white), with the pixels within 2 px of a visible UV seam tinted: red for
seams on smooth surface, orange for seams along creases.

:class:`SceneRequest` declares the command's inputs once (``pipeline.fields``) and checks
itself when built, before anything is written.
"""

from __future__ import annotations

import dataclasses
import io
import os
import time
from dataclasses import dataclass

import numpy as np

from geometry import build_shaderball, default_camera
from pipeline.fields import Checked, field, same_as
from pipeline.fields.rules import Path, format_value
from pipeline.image.srgb import srgb_encode
from pipeline.render.gbuffer import gbuffer_key_inputs, load_gbuffer, seam_band
from pipeline.render.mitsuba_env import load_mitsuba, resolve_variant
from pipeline.render.scene import bitmap_texture, sensor_dict, shape_dicts
from pipeline.render.settings import RenderSettings
from pipeline.store.atomic import write_bytes_atomic
from pipeline.store.exr import write_exr

PREVIEW_SPP = 64
PREVIEW_SEED = 0
#: Checker squares along the atlas's side (about 7 cm on the ball at the default sizes).
CHECKER_SQUARES = 48
CHECKER_COLOURS = ((0.80, 0.80, 0.80), (0.05, 0.20, 0.55))
SEAM_PX = 2.0


@dataclass(frozen=True)
class SceneRequest(Checked):
    """What `shaderball scene` is asked: where to write, at what resolution, on which backend."""

    out: str = field(
        rule=Path("a folder (created if missing)"),
        doc="Output folder; created if missing. Receives shaderball.ply, gbuffer.exr, preview.png.",
        metavar="DIR",
    )
    resolution: int = same_as(RenderSettings, "resolution")
    variant: str = same_as(
        RenderSettings, "variant", doc="Mitsuba backend: auto picks cuda when a GPU works, else llvm (the CPU)."
    )

    def check_cross(self) -> None:
        if os.path.exists(self.out) and not os.path.isdir(self.out):
            raise self.field_error(
                "out", self.out, "a folder (created if missing)", what=f"{format_value(self.out)} is a file"
            )


@dataclass(frozen=True)
class SceneSummary:
    out_dir: str
    resolution: int
    files: dict[str, str]
    vertices: int
    faces: int
    charts: int
    mask_share: float
    seam_share: float
    seam_share_off_crease: float
    timings: dict[str, float] = dataclasses.field(default_factory=dict)

    def lines(self) -> list[str]:
        t = self.timings
        return [
            f"wrote {self.files['mesh']} ({self.vertices} vertices, {self.faces} triangles, {self.charts} UV charts)",
            f"wrote {self.files['gbuffer']} ({self.resolution}x{self.resolution}, "
            f"material mask {100 * self.mask_share:.1f}% of pixels)",
            f"wrote {self.files['preview']}",
            f"seams: {100 * self.seam_share:.2f}% of ball pixels within {SEAM_PX:g} px of a visible UV seam, "
            f"{100 * self.seam_share_off_crease:.2f}% counting only seams off creases",
            "time: " + ", ".join(f"{k} {v:.2f} s" for k, v in t.items()),
        ]


def checker_texture(squares: int = CHECKER_SQUARES) -> np.ndarray:
    i, j = np.mgrid[0:squares, 0:squares]
    odd = ((i + j) % 2).astype(bool)
    tex = np.empty((squares, squares, 3), np.float32)
    tex[~odd] = CHECKER_COLOURS[0]
    tex[odd] = CHECKER_COLOURS[1]
    return tex


def render_preview(
    ball, camera, resolution: int, variant: str, spp: int = PREVIEW_SPP, seed: int = PREVIEW_SEED
) -> np.ndarray:
    """(H, W, 3) linear RGB: the ball with a checker through its atlas, under simple light."""
    mi = load_mitsuba(variant)
    material = {
        "type": "diffuse",
        "reflectance": bitmap_texture(checker_texture(), filter_type="nearest", variant=variant),
    }
    to_light = np.array([-0.55, -0.75, 0.9])
    to_light /= np.linalg.norm(to_light)
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 6},
        **shape_dicts(ball, material),
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": 0.35}},
        "sun": {
            "type": "directional",
            "direction": (-to_light).tolist(),
            "irradiance": {"type": "rgb", "value": 2.2},
        },
        "sensor": sensor_dict(camera, resolution, spp, seed=seed, variant=variant),
    }
    return np.array(mi.render(mi.load_dict(scene), seed=seed), dtype=np.float32)


def srgb8(linear: np.ndarray) -> np.ndarray:
    return np.round(srgb_encode(linear) * 255.0).astype(np.uint8)


def mask_panel(mask: np.ndarray, seams_smooth: np.ndarray, seams_crease: np.ndarray) -> np.ndarray:
    panel = np.full(mask.shape + (3,), 40, np.uint8)
    panel[mask] = 235
    panel[seams_crease] = (245, 160, 60)
    panel[seams_smooth] = (220, 30, 30)
    return panel


def encode_png(image: np.ndarray) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG", optimize=False)
    return buffer.getvalue()


def write_scene(request: SceneRequest) -> SceneSummary:
    """Write ``shaderball.ply``, ``gbuffer.exr`` and ``preview.png`` into ``request.out``.

    ``request`` was checked when built (nothing is written before); each file is written
    atomically. Its variant, a spec-style choice (auto, llvm, cuda, ...), is resolved once.
    """
    out_dir, resolution = request.out, request.resolution
    variant = resolve_variant(request.variant)
    timings: dict[str, float] = {}
    t = time.perf_counter()
    ball = build_shaderball()
    camera = default_camera(ball.params)
    timings["geometry"] = time.perf_counter() - t

    t = time.perf_counter()
    gbuffer = load_gbuffer(ball, camera, resolution, variant)
    timings["gbuffer"] = time.perf_counter() - t

    t = time.perf_counter()
    seams_all = seam_band(gbuffer, ball, SEAM_PX)
    seams_smooth = seam_band(gbuffer, ball, SEAM_PX, include_creases=False)
    timings["seams"] = time.perf_counter() - t

    t = time.perf_counter()
    render = render_preview(ball, camera, resolution, variant)
    panel = mask_panel(gbuffer.mask, seams_smooth, seams_all & ~seams_smooth)
    preview = np.concatenate([srgb8(render), panel], axis=1)
    timings["preview"] = time.perf_counter() - t

    with open(ball.mesh_files["material"], "rb") as fh:
        mesh_bytes = fh.read()
    files = {
        "mesh": os.path.join(out_dir, "shaderball.ply"),
        "gbuffer": os.path.join(out_dir, "gbuffer.exr"),
        "preview": os.path.join(out_dir, "preview.png"),
    }
    write_bytes_atomic(files["mesh"], mesh_bytes)
    write_exr(files["gbuffer"], gbuffer.layers(), gbuffer_key_inputs(ball, camera, resolution, variant))
    write_bytes_atomic(files["preview"], encode_png(preview))

    mask_count = max(1, int(gbuffer.mask.sum()))
    return SceneSummary(
        out_dir=out_dir,
        resolution=resolution,
        files=files,
        vertices=len(ball.material_mesh.vertices),
        faces=len(ball.material_mesh.faces),
        charts=len(ball.chart_names),
        mask_share=float(gbuffer.mask.mean()),
        seam_share=float(seams_all.sum()) / mask_count,
        seam_share_off_crease=float(seams_smooth.sum()) / mask_count,
        timings=timings,
    )
