"""A trained network as a TorchScript file, for use without this package.

``export_torchscript(request)`` traces the run's network (its checkpoint: last, best or a
file, as `infer`'s) in eval mode and saves it with ``torch.jit.save``. The file needs only torch:

    net = torch.jit.load("net.pt")
    image = net(maps, light)   # maps (N, 12, R, R) in [0, 1]; light (N, 4): (3 d, turbidity)

``maps`` are the 12 input channels (diffuse RGB, specular RGB, normal-map colour RGB,
roughness x3); ``light`` is the network's light input, the lighting vector with its
direction scaled to length 3 (``network.light_input``); the output is the tone-mapped
image in [0, 1] (``pipeline.image.tonemap``; the exposure is in the file's extra
``shaderball.json``). Tracing records one resolution: the run's.

    shaderball export RUN --out net.pt [--checkpoint best]
"""

from __future__ import annotations

import io
import json
import warnings

import torch

from pipeline.neural import runfiles
from pipeline.neural.config import ExportRequest
from pipeline.neural.infer import load_run_model
from pipeline.neural.network import INPUT_CHANNELS, LIGHT_CHANNELS
from pipeline.store.atomic import write_bytes_atomic

EXTRA = "shaderball.json"


def example_inputs(resolution: int, batch: int = 1, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Inputs in the network's ranges: maps in [0, 1], a light input of a unit direction x 3."""
    g = torch.Generator().manual_seed(seed)
    maps = torch.rand(batch, INPUT_CHANNELS, resolution, resolution, generator=g)
    d = torch.nn.functional.normalize(torch.rand(batch, 3, generator=g) + 0.1, dim=1) * 3.0
    light = torch.cat([d, 1.0 + 9.0 * torch.rand(batch, LIGHT_CHANNELS - 3, generator=g)], dim=1)
    return maps, light


def export_torchscript(req: ExportRequest) -> dict:
    """Write the run's network as TorchScript to ``req.out``; returns what the file's extra holds."""
    runfiles.refuse_links(ExportRequest, "out", req.out, [req.network.run], [req.out])  # a file inside RUN: no link
    model, config = load_run_model(req.network.run, torch.device("cpu"), req.network.checkpoint)
    meta = {
        "format": "shaderball-neural-torchscript",
        "resolution": model.resolution,
        "inputs": "maps (N, 12, R, R) in [0, 1]; light (N, 4) = (3 d_x, 3 d_y, 3 d_z, turbidity)",
        "output": "(N, 3, R, R) in [0, 1], sRGB-encoded Reinhard tone map of linear radiance",
        "tonemap": config.get("tonemap"),
        "checkpoint": req.network.checkpoint,
        "identity_digest": config.get("identity_digest"),
        "torch": torch.__version__,
    }
    # The tracer warns where the network turns a tensor into a Python number (its resolution
    # checks): true for every input of the traced resolution, which is the only one the file takes.
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore", torch.jit.TracerWarning)
        traced = torch.jit.trace(model, example_inputs(model.resolution), check_trace=False)
    buffer = io.BytesIO()
    torch.jit.save(traced, buffer, _extra_files={EXTRA: json.dumps(meta, sort_keys=True)})
    write_bytes_atomic(req.out, buffer.getvalue(), inside=req.network.run)
    return meta
