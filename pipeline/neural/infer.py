"""`shaderball infer`: the network's picture of one material under one sun, no path tracing.

The material and sun options are `shaderball render`'s (checked by the same code); the
screen-space maps are made through the G-buffer exactly as a dataset's are, at the run's
network resolution; the lighting vector is the low-sun policy's effective light, as a
dataset record stores it.
"""

from __future__ import annotations

import io
import os
import time
from dataclasses import dataclass

import numpy as np
import torch
from PIL import Image

from geometry import build_shaderball, default_camera
from pipeline.errors import ShaderballError
from pipeline.image.tonemap import inverse_tonemap, to_srgb8
from pipeline.neural import runfiles
from pipeline.neural.config import InferRequest
from pipeline.neural.data import assemble_maps
from pipeline.neural.network import NeuralRenderer, light_input, network_from_config
from pipeline.neural.scene_inputs import InputPlan, geometry_channels
from pipeline.neural.train import pick_device
from pipeline.render.gbuffer import load_gbuffer
from pipeline.render.mitsuba_env import resolve_variant
from pipeline.render.raster import project_material
from pipeline.store.atomic import write_bytes_atomic
from pipeline.store.exr import write_exr
from sky.policy import apply_policy


@dataclass
class InferSummary:
    out: str
    png: str | None
    resolution: int
    device: str
    load_s: float
    maps_s: float
    network_s: float
    lighting_vector: list

    def lines(self) -> list[str]:
        return [
            f"wrote {self.out}" + (f" and {self.png}" if self.png else ""),
            f"{self.resolution}x{self.resolution} on {self.device}: maps {self.maps_s * 1000:.1f} ms (G-buffer "
            f"lookup), network {self.network_s * 1000:.1f} ms; loading the run {self.load_s * 1000:.0f} ms",
            "lighting vector (d_x, d_y, d_z, turbidity): " + ", ".join(f"{v:.4f}" for v in self.lighting_vector),
        ]


def load_run_model(run_dir: str, device: torch.device, checkpoint: str = "last") -> tuple[NeuralRenderer, dict]:
    """The trained network of a run (eval mode, on ``device``) and its config; ``checkpoint``:
    ``last`` (the last epoch's), ``best`` (the best held-out PSNR's) or a checkpoint file of
    this run's configuration. The config and the checkpoint are untrusted input (runfiles)."""
    config = runfiles.read_config(run_dir)
    model = network_from_config(config["network"], where=f"{os.path.join(run_dir, runfiles.CONFIG)}: network")
    ckpt = runfiles.load_checkpoint(run_dir, config["identity_digest"], checkpoint, network=model)
    try:
        model.load_state_dict(ckpt["model"])
    except RuntimeError as exc:
        raise runfiles.weights_mismatch(
            exc, runfiles.checkpoint_path(run_dir, checkpoint), checkpoint, os.path.join(run_dir, runfiles.CONFIG)
        ) from None
    return model.to(device).eval(), config


def refuse_nonfinite(output: np.ndarray, what: str) -> np.ndarray:
    """``output`` if every value is finite, else a ShaderballError: nothing is written of it."""
    bad = int(np.count_nonzero(~np.isfinite(output)))
    if bad:
        raise ShaderballError(
            f"{what}: {bad} of {output.size} output values are NaN or infinite; nothing written "
            "(the weights are finite: the input maps or lighting are outside what the network was trained on)"
        )
    return output


def _synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


@torch.no_grad()
def run_network(
    model: NeuralRenderer, maps_chw: np.ndarray, lighting_vector, device: torch.device, environment: int | None = None
) -> np.ndarray:
    """One (C, R, R) input (the 12 maps, and the geometry channels of a run trained with them) and
    a lighting vector -> (R, R, 3) network output in [0, 1]; ``environment``: the row of the map's
    code, for a network that has codes (None: row 0)."""
    maps = torch.from_numpy(np.ascontiguousarray(maps_chw, dtype=np.float32))[None].to(device)
    light = light_input(torch.tensor([list(lighting_vector)], dtype=torch.float32, device=device))
    extra = () if environment is None else (torch.tensor([environment], dtype=torch.long, device=device),)
    return model(maps, light, *extra)[0].permute(1, 2, 0).float().cpu().numpy()


def refuse_run_links(req: InferRequest) -> None:
    """Refuse an output file inside the run folder that is, or passes through, a link there."""
    for field in ("out", "png"):
        path = getattr(req, field)
        if path:
            runfiles.refuse_links(InferRequest, field, path, [req.network.run], [path])


def infer_to_files(req: InferRequest) -> InferSummary:
    """The network's picture of ``req``'s material under its sun, written to ``req.out`` (and
    ``req.png``); nothing is written before every check passed (nor inside the run folder
    through a link in it)."""
    refuse_run_links(req)
    device = pick_device(req.device)
    started = time.perf_counter()
    model, config = load_run_model(req.network.run, device, req.network.checkpoint)
    load_s = time.perf_counter() - started
    resolution = model.resolution
    material = req.material.maps()
    effective, _ = apply_policy(req.sun_sky.light())
    vector = [float(v) for v in effective.lighting_vector()]

    started = time.perf_counter()
    variant = resolve_variant((config["identity"].get("dataset") or {}).get("variant") or "auto")
    gbuffer = load_gbuffer(build_shaderball(), default_camera(), resolution, variant)
    inputs = InputPlan.of_network(config["network"])
    screen = project_material(material, gbuffer, geometry=inputs.geometry)  # the run's input channels
    layers = {k: (v[..., None] if v.ndim == 2 else v) for k, v in screen.items()}
    maps_chw, _ = assemble_maps(layers)
    if inputs.geometry:
        maps_chw = np.concatenate([maps_chw, geometry_channels(layers)])
    maps_s = time.perf_counter() - started

    run_network(model, maps_chw, vector, device)  # warm-up: first calls allocate
    _synchronize(device)
    started = time.perf_counter()
    output = run_network(model, maps_chw, vector, device)
    _synchronize(device)
    network_s = time.perf_counter() - started
    refuse_nonfinite(output, f"the network of {req.network.run}")

    exposure = float(config["tonemap"]["exposure"])
    meta = {
        "estimate": "neural renderer (KT et al. 2019)",
        "run": req.network.run,
        "lighting_vector": vector,
        "tonemap": config["tonemap"],
        "colorspace": "linear Rec.709 (sRGB primaries, D65)",
    }
    refuse_run_links(req)
    write_exr(
        req.out,
        {"render": inverse_tonemap(output, exposure), **screen},
        meta,
        half=("diffuse", "specular", "roughness", "normal", "mask"),
    )
    if req.png:
        buffer = io.BytesIO()
        Image.fromarray(to_srgb8(output)).save(buffer, format="PNG")
        write_bytes_atomic(req.png, buffer.getvalue(), inside=req.network.run)
    return InferSummary(req.out, req.png, resolution, str(device), load_s, maps_s, network_s, vector)
