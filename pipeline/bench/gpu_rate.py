"""The per-GPU render rate `plan --gpus` / `--gpus-per-job` estimates from, and where it came from.

Measured: the plan's own timed renders when they ran on a GPU (the spec's variant resolved to
cuda here). Otherwise the recorded figure of docs/results/gpu-rate.json (one H200 at the paper's
400 px / 150 spp), scaled to the spec's pixels x spp (render time grows with both). Each
estimate names which one it used; nothing is guessed silently.
"""

from __future__ import annotations

import json
from pathlib import Path

RATE_FILE = Path(__file__).resolve().parents[2] / "docs" / "results" / "gpu-rate.json"


def recorded_rate(resolution: int, spp: int, path: Path = RATE_FILE) -> tuple[float, str]:
    """(renders a second on one GPU at ``resolution`` px and ``spp``, what it is from)."""
    figure = json.loads(path.read_text())
    scale = (figure["resolution"] ** 2 * figure["spp"]) / (resolution**2 * spp)
    rate = figure["renders_per_s"] * scale
    source = (
        f"recorded {figure['renders_per_s']} renders/s on one {figure['gpu']} at {figure['resolution']} px/"
        f"{figure['spp']} spp ({figure['measured']}, {path.relative_to(path.parents[2])}), "
        f"scaled by pixels x spp to {resolution} px/{spp} spp"
    )
    return rate, source


def gpu_rate(resolution: int, spp: int, timed_variant: str | None, seconds_per_render: float | None):
    """(renders a second per GPU, its source): measured when the plan's renders ran on cuda."""
    if timed_variant and timed_variant.startswith("cuda") and seconds_per_render:
        return 1.0 / seconds_per_render, "measured: this plan's renders on this machine's GPU"
    return recorded_rate(resolution, spp)
