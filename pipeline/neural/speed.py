"""How a training step runs, not what it computes: torch threads, memory format, precision
and compilation (`shaderball train --threads/--channels-last/--precision/--compile`).
`shaderball neural-bench train-options` measures the effect of each on a machine
(docs/neural.md, "Speed on a CPU").

- precision ``bf16``: autocast to bfloat16 (CPU or CUDA); ``fp16``: autocast to float16 with
  a gradient scaler, CUDA only. Weights, optimiser state and the loss stay float32. ``auto``
  (the default): bf16 on a CPU that computes bfloat16 in hardware (:func:`native_bf16`), else
  fp32.
- threads 0 (the default): torch's own count (the cores this process may run on: its CPU
  affinity, OMP_NUM_THREADS), at most the cores its cgroup's CPU quota grants
  (:func:`available_cores`).
- ``channels_last``: the network's and the VGG's weights and the batches in NHWC.
- ``compile``: ``torch.compile`` of the network for the step; the weights saved are the
  uncompiled module's (the same state dict keys).
"""

from __future__ import annotations

import contextlib
import math
import os

import torch

from pipeline.neural.config import TrainConfig
from pipeline.neural.limits import PRECISIONS

DTYPES = {"bf16": torch.bfloat16, "fp16": torch.float16}


#: /proc/cpuinfo flags of an x86 CPU that computes bfloat16 in hardware: there bf16 trains
#: faster than fp32. Elsewhere oneDNN emulates it: 5.4x slower than fp32 on an AVX2 EPYC,
#: also on AVX-512 CPUs without these (oneDNN's own bf16 test, which torch asks, is true there).
BF16_FLAGS = ("avx512_bf16", "amx_bf16")
#: ONEDNN_MAX_CPU_ISA values that keep oneDNN to instructions without bfloat16 arithmetic.
NO_BF16_ISAS = ("SSE41", "AVX", "AVX2", "AVX2_VNNI", "AVX2_VNNI_2", "AVX512_CORE", "AVX512_CORE_VNNI")
#: The most of /proc/cpuinfo read for the flags (its first CPU's lines come first).
CPUINFO_BYTES = 1 << 20


def cpu_flags(cpuinfo: str) -> set[str]:
    """The first CPU's ``flags`` in the text of /proc/cpuinfo (empty where there is none)."""
    for line in cpuinfo.splitlines():
        name, _, value = line.partition(":")
        if name.strip() == "flags":
            return set(value.split())
    return set()


def native_bf16(cpuinfo: str | None = None, environ=None) -> bool:
    """Whether this CPU computes bfloat16 in hardware (:data:`BF16_FLAGS`) and oneDNN may use
    it (``ONEDNN_MAX_CPU_ISA`` not one of :data:`NO_BF16_ISAS`). ``cpuinfo``: /proc/cpuinfo's
    text (default: read; none, as on other systems than Linux: False)."""
    environ = os.environ if environ is None else environ
    if environ.get("ONEDNN_MAX_CPU_ISA", "").strip().upper() in NO_BF16_ISAS:
        return False
    if cpuinfo is None:
        try:
            with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
                cpuinfo = f.read(CPUINFO_BYTES)
        except OSError:
            return False
    return bool(cpu_flags(cpuinfo) & set(BF16_FLAGS))


def resolve_precision(precision: str, device: torch.device) -> str:
    """``precision`` with ``auto`` made concrete for ``device`` (checked): bf16 on a CPU that
    computes bfloat16 in hardware (:func:`native_bf16`; 2.1x with --channels-last on such a
    machine, the same held-out loss: docs/neural.md), fp32 elsewhere (CUDA: mixed precision
    untested here)."""
    if precision == "auto":
        precision = "bf16" if device.type == "cpu" and native_bf16() else "fp32"
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


def cgroup_cores(cpu_max: str) -> int | None:
    """The cores a cgroup v2 ``cpu.max`` (``"QUOTA PERIOD"``, or ``"max PERIOD"``) grants,
    rounded up; None where it sets no quota."""
    parts = cpu_max.split()
    try:
        quota, period = int(parts[0]), int(parts[1])
    except (IndexError, ValueError):
        return None
    return max(1, math.ceil(quota / period)) if quota > 0 and period > 0 else None


def _quota_cores() -> int | None:
    """This process's cgroup CPU quota in cores (v2, else v1), or None."""
    try:
        with open("/sys/fs/cgroup/cpu.max", encoding="ascii") as f:
            return cgroup_cores(f.read(256))
    except OSError:
        pass
    try:
        with open("/sys/fs/cgroup/cpu/cpu.cfs_quota_us") as q, open("/sys/fs/cgroup/cpu/cpu.cfs_period_us") as p:
            return cgroup_cores(f"{q.read(64).strip()} {p.read(64).strip()}")
    except OSError:
        return None


def available_cores() -> int:
    """torch's thread count (which follows the process's CPU affinity and OMP_NUM_THREADS), at
    most the cores of its cgroup's CPU quota, which torch does not read: a container granted 2
    CPUs of a 64-core host would otherwise run 64 threads on 2 cores' time."""
    quota = _quota_cores()
    threads = torch.get_num_threads()
    return min(threads, quota) if quota else threads


def threads_for(threads: int) -> int:
    """The intra-op threads ``--threads`` means (0: :func:`available_cores`)."""
    return threads or available_cores()


@contextlib.contextmanager
def torch_threads(threads: int):
    """``threads`` intra-op threads inside (0: :func:`available_cores`); torch's setting after."""
    before = torch.get_num_threads()
    torch.set_num_threads(threads_for(threads))
    try:
        yield
    finally:
        torch.set_num_threads(before)
