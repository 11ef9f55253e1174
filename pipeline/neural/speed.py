"""How a training step runs, not what it computes: torch threads, memory format, precision
and compilation (`shaderball train --threads/--channels-last/--precision/--compile`).
`shaderball neural-bench train-options` measures the effect of each on a machine
(docs/neural.md, "Speed on a CPU").

- precision ``bf16``: autocast to bfloat16 (CPU or CUDA); ``fp16``: autocast to float16 with
  a gradient scaler, CUDA only. Weights, optimiser state and the loss stay float32.
- ``channels_last``: the network's and the VGG's weights and the batches in NHWC.
- ``compile``: ``torch.compile`` of the network for the step; the weights saved are the
  uncompiled module's (the same state dict keys).
"""

from __future__ import annotations

import contextlib

import torch

from pipeline.neural.config import TrainConfig
from pipeline.neural.limits import PRECISIONS

DTYPES = {"bf16": torch.bfloat16, "fp16": torch.float16}


def resolve_precision(precision: str, device: torch.device) -> str:
    """``precision`` with ``auto`` made concrete for ``device`` (checked): bf16 on a CPU where
    oneDNN has bfloat16 kernels (2.1x with --channels-last on the project's machine, the same
    held-out loss: docs/neural.md), fp32 elsewhere (CUDA: mixed precision untested here)."""
    if precision == "auto":
        cpu_bf16 = device.type == "cpu" and torch.ops.mkldnn._is_mkldnn_bf16_supported()
        precision = "bf16" if cpu_bf16 else "fp32"
    check_precision(precision, device)
    return precision


def check_precision(precision: str, device: torch.device) -> None:
    if precision not in PRECISIONS or precision == "auto":
        raise TrainConfig.field_error("precision", precision, ", ".join(p for p in PRECISIONS if p != "auto"))
    if precision == "fp16" and device.type != "cuda":
        raise TrainConfig.field_error("precision", precision, "fp32 or bf16 on a CPU (fp16 autocast is for CUDA)")


def autocast(device: torch.device, precision: str):
    """The context a forward pass and its loss run in."""
    if precision == "fp32":
        return contextlib.nullcontext()
    return torch.autocast(device.type, dtype=DTYPES[precision])


def grad_scaler(device: torch.device, precision: str) -> torch.amp.GradScaler:
    """A scaler that does something only for fp16 on CUDA (bf16 has float32's range)."""
    return torch.amp.GradScaler(device.type, enabled=precision == "fp16" and device.type == "cuda")


def memory_format(channels_last: bool) -> torch.memory_format:
    return torch.channels_last if channels_last else torch.contiguous_format


def step_forward(model: torch.nn.Module, loss_fn: torch.nn.Module, channels_last: bool, compile: bool):
    """Moves the modules to the memory format; returns the callable a step runs the network with."""
    fmt = memory_format(channels_last)
    model.to(memory_format=fmt)
    loss_fn.to(memory_format=fmt)
    return torch.compile(model) if compile else model


@contextlib.contextmanager
def torch_threads(threads: int):
    """``threads`` intra-op threads inside (0: leave torch's setting as it is)."""
    before = torch.get_num_threads()
    if threads:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)
