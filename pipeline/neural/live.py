"""The trained network as an interactive page calls it: screen-space maps and a light in, a
linear HDR picture and the time it took out (`shaderball serve`, docs/serve.md).

The maps are those of :func:`pipeline.render.raster.project_material` at the network's
resolution (the G-buffer lookup a dataset's maps come from); the lighting vector is the
low-sun policy's effective light, as `shaderball infer` gives it.
"""

from __future__ import annotations

import time

import numpy as np
import torch

from pipeline.image.tonemap import inverse_tonemap
from pipeline.neural.data import assemble_maps
from pipeline.neural.infer import load_run_model, run_network
from pipeline.neural.train import pick_device
from sky import Light
from sky.policy import apply_policy


class LiveNetwork:
    """A run's network, loaded once, on the CPU (or ``device``), with ``threads`` torch threads."""

    def __init__(self, run_dir: str, checkpoint: str = "last", device: str = "cpu", threads: int = 0):
        if threads > 0:
            torch.set_num_threads(int(threads))
        self.device = pick_device(device)
        self.model, self.config = load_run_model(run_dir, self.device, checkpoint)
        self.run_dir = run_dir
        self.resolution = int(self.model.resolution)
        self.exposure = float(self.config["tonemap"]["exposure"])

    def describe(self) -> dict:
        network = self.config.get("network", {})
        return {
            "run": self.run_dir,
            "resolution": self.resolution,
            "width": float(network.get("width", 1.0)),
            "device": str(self.device),
            "threads": torch.get_num_threads(),
            "exposure": self.exposure,
        }

    @staticmethod
    def lighting_vector(light: Light) -> list[float]:
        if not isinstance(light, Light):  # an environment map: its record's 4 numbers, as a build stores them
            return [float(v) for v in light.lighting_vector()]
        effective, _ = apply_policy(light)
        return [float(v) for v in effective.lighting_vector()]

    def __call__(self, screen: dict[str, np.ndarray], light: Light) -> tuple[np.ndarray, float]:
        """(H, W, 3) linear HDR estimate and the seconds the network took (maps assembly included)."""
        started = time.perf_counter()
        layers = {k: (v[..., None] if v.ndim == 2 else v) for k, v in screen.items()}
        maps_chw, _ = assemble_maps(layers)
        output = run_network(self.model, maps_chw, self.lighting_vector(light), self.device)
        seconds = time.perf_counter() - started
        return inverse_tonemap(output, self.exposure), seconds
