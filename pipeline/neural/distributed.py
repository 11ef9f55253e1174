"""`shaderball train --devices N`: DistributedDataParallel over N processes, one a device.

The command's process spawns N processes (torch.multiprocessing, ``spawn``: no torchrun), which
meet through a file in a temporary folder and form one process group: ``gloo`` on a CPU, ``nccl``
on CUDA (rank r on ``cuda:r``). Each runs :func:`pipeline.neural.train._train` with a
:class:`Ranks`: every global batch of ``batch_size`` samples (the one-process run's, in its order)
is split into N equal parts, rank r taking every N-th sample as torch's DistributedSampler does
(padding the epoch to a multiple of N with its first samples, so when the training set's size is
not a multiple of N the last batch repeats at most N-1 samples); DDP averages the gradients, and
BatchNorm's statistics are the whole batch's (SyncBatchNorm; on a CPU, where torch's SyncBatchNorm
does not run, :class:`CpuSyncBatchNorm`). So the run computes what one process would with the
same ``batch_size``, up to the order of float sums. Rank 0 alone scores the epochs and writes
config.json, the checkpoints and the logs; its progress goes to the command's process. A rank
that fails ends every process, and the command raises one error naming it.
"""

from __future__ import annotations

import datetime
import multiprocessing.connection
import os
import pickle
import shutil
import signal
import tempfile
import warnings

import torch
import torch.distributed as dist
import torch.distributed.nn.functional as dist_nn
from torch import nn

from pipeline.errors import ShaderballError
from pipeline.neural import speed
from pipeline.neural.config import TrainConfig

#: How long a rank waits for the others in one collective (rank 0 scores and saves each epoch
#: alone); a rank that dies is found by the command's process well before.
TIMEOUT = datetime.timedelta(hours=4)
#: Test hook: "RANK:STEP" makes that rank raise after that many training steps; "RANK:STEP:kill"
#: makes it kill itself (SIGKILL) instead.
FAIL_HOOK = "SHADERBALL_TEST_RANK_FAILS"


class Ranks:
    """One process's place in the group: its rank of ``world``, its device."""

    def __init__(self, rank: int, world: int, device: torch.device):
        self.rank, self.world, self.device = rank, world, device
        self.steps = 0
        hook = os.environ.get(FAIL_HOOK, "").split(":")
        self.fail = (int(hook[1]), hook[2:] == ["kill"]) if hook[0] == str(rank) else None

    @property
    def main(self) -> bool:
        return self.rank == 0

    def shard(self, order: list[int]) -> list[int]:
        """This rank's samples of an epoch's ``order``: DistributedSampler's (padded to a multiple
        of the world size with the first samples, then every world-th from the rank's)."""
        total = -(-len(order) // self.world) * self.world
        padded = (order * (-(-total // len(order))))[:total] if order else []
        return padded[self.rank :: self.world]

    def batch_means(self, values: dict[str, float], n: int) -> tuple[dict[str, float], int]:
        """The whole batch's mean of each of this rank's ``values`` (means over its ``n`` samples)
        and the batch's size: every rank's, summed."""
        self.steps += 1
        if self.fail is not None and self.steps == self.fail[0]:
            if self.fail[1]:
                os.kill(os.getpid(), signal.SIGKILL)
            raise RuntimeError(f"{FAIL_HOOK}: rank {self.rank} fails after step {self.steps}")
        keys = list(values)
        sums = torch.tensor([values[k] * n for k in keys] + [n], dtype=torch.float64, device=self.device)
        dist.all_reduce(sums)
        total = float(sums[-1])
        return {k: float(sums[i]) / total for i, k in enumerate(keys)}, int(total)

    def sync_batchnorm(self, model: nn.Module) -> nn.Module:
        """``model`` with its BatchNorm layers computing the whole batch's statistics (the same
        state dict keys, so a checkpoint loads in a one-process network)."""
        if self.device.type == "cuda":
            return nn.SyncBatchNorm.convert_sync_batchnorm(model)
        return CpuSyncBatchNorm.convert(model)

    def wrap(self, model: nn.Module, compile: bool):
        """The callable a training step runs: ``model`` in DistributedDataParallel."""
        ids = [self.device.index] if self.device.type == "cuda" else None
        ddp = nn.parallel.DistributedDataParallel(model, device_ids=ids)
        return torch.compile(ddp) if compile else ddp

    def barrier(self) -> None:
        dist.barrier(device_ids=[self.device.index]) if self.device.type == "cuda" else dist.barrier()


class CpuSyncBatchNorm(nn.BatchNorm2d):
    """BatchNorm2d whose training statistics are every rank's batch's (sums all-reduced through
    autograd, so the gradients are the whole batch's too); in eval mode a plain BatchNorm2d."""

    @classmethod
    def convert(cls, module: nn.Module) -> nn.Module:
        if isinstance(module, nn.BatchNorm2d):
            sync = cls(module.num_features, module.eps, module.momentum, module.affine, module.track_running_stats)
            sync.load_state_dict(module.state_dict())
            return sync
        for name, child in module.named_children():
            module.add_module(name, cls.convert(child))
        return module

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.training:
            return super().forward(x)
        shape = (1, -1, 1, 1)
        xf = x.float()
        count = torch.tensor([x.numel() // x.shape[1]], dtype=torch.float32)
        total = dist_nn.all_reduce(torch.cat([xf.sum((0, 2, 3)), count]))
        n = total[-1]
        mean = total[:-1] / n
        centred = xf - mean.view(shape)
        var = dist_nn.all_reduce((centred * centred).sum((0, 2, 3))) / n  # two passes: no cancellation
        if self.track_running_stats:
            with torch.no_grad():
                self.num_batches_tracked += 1
                m = self.momentum if self.momentum is not None else 1.0 / float(self.num_batches_tracked)
                self.running_mean.mul_(1 - m).add_(mean.detach(), alpha=m)
                self.running_var.mul_(1 - m).add_(var.detach() * (n / (n - 1)), alpha=m)
        y = centred * torch.rsqrt(var + self.eps).view(shape)
        if self.affine:
            y = y * self.weight.view(shape) + self.bias.view(shape)
        return y.to(x.dtype)


def check_devices(devices: int, device: torch.device) -> None:
    """Refuse more CUDA processes than torch sees GPUs."""
    if device.type == "cuda" and devices > torch.cuda.device_count():
        raise TrainConfig.field_error(
            "devices", devices, f"at most {torch.cuda.device_count()}, the GPUs torch sees (or {{device}} cpu)"
        )


def train_distributed(config: TrainConfig, progress, source, device: torch.device, run):
    """Train ``config`` in ``config.devices`` processes, each calling ``run`` (pipeline.neural.train._train)
    with its :class:`Ranks`; rank 0's TrainSummary."""
    check_devices(config.devices, device)
    ctx = torch.multiprocessing.get_context("spawn")
    events = ctx.SimpleQueue()
    folder = tempfile.mkdtemp(prefix="shaderball-ddp-")
    init = "file://" + os.path.join(folder, "rendezvous")
    procs = torch.multiprocessing.start_processes(
        _rank_main,
        args=(run, config, source, device.type, init, events),
        nprocs=config.devices,
        join=False,
        start_method="spawn",
    )
    summary, failures, ended = None, [], None
    try:
        while ended is None:
            codes = [p.exitcode for p in procs.processes]
            ended = next(((rank, c) for rank, c in enumerate(codes) if c not in (None, 0)), None)
            multiprocessing.connection.wait([p.sentinel for p in procs.processes if p.is_alive()], timeout=0.2)
            while not events.empty():
                kind, payload = events.get()
                if kind == "progress" and progress is not None:
                    progress(payload)
                elif kind == "summary":
                    summary = payload
                elif kind == "failed":
                    failures.append(payload)
            if all(c == 0 for c in codes):
                break
    finally:
        stopped = [p.is_alive() for p in procs.processes]  # the others of a failed rank (all, on an interrupt)
        for p, alive in zip(procs.processes, stopped):
            if alive:
                p.terminate()
        for p in procs.processes:
            p.join()
        shutil.rmtree(folder, ignore_errors=True)
    if ended is not None or summary is None:
        told = {rank for rank, _, _ in failures}
        silent = [
            (rank, p.exitcode)
            for rank, (p, by_us) in enumerate(zip(procs.processes, stopped))
            if p.exitcode and not by_us and rank not in told
        ]
        raise _failure(config.devices, failures, silent[0] if silent else ended)
    summary.device = f"{config.devices} x {device.type} (DistributedDataParallel)"
    return summary


def _failure(world: int, failures: list, ended) -> ShaderballError:
    """The first rank's failure (the others' follow from it) as one error: a rank that ended
    without a word (killed), else the first that said why."""
    if ended is not None and ended[0] not in {rank for rank, _, _ in failures}:
        rank, code = ended
        how = f"by signal {signal.Signals(-code).name}" if code < 0 else f"with exit code {code}"
        what = f"training process {rank} of {world} ended {how}"
    elif failures:
        rank, line, error = failures[0]
        if error is not None:
            return error
        what = f"training process {rank} of {world} failed: {line}"
    else:
        what = f"a training process of {world} ended without a result"
    return ShaderballError(f"{what}; every process stopped; the run keeps what it saved: the same command resumes it")


def _rank_main(rank: int, run, config: TrainConfig, source, device_type: str, init: str, events) -> None:
    """One rank: join the group, ``run``, send rank 0's summary (or this rank's failure) to ``events``."""
    warnings.filterwarnings("ignore", "torch.distributed.nn.functional.all_reduce is deprecated", FutureWarning)
    try:
        device = torch.device(device_type, rank) if device_type == "cuda" else torch.device("cpu")
        if device.type == "cuda":
            torch.cuda.set_device(device)
        backend = "nccl" if device.type == "cuda" else "gloo"
        dist.init_process_group(backend, init_method=init, rank=rank, world_size=config.devices, timeout=TIMEOUT)
        threads = config.threads or (max(1, speed.available_cores() // config.devices) if backend == "gloo" else 0)
        progress = (lambda event: events.put(("progress", event))) if rank == 0 else None
        with speed.torch_threads(threads):
            summary = run(config, progress, source, device, Ranks(rank, config.devices, device))
        if rank == 0:
            events.put(("summary", summary))
        dist.destroy_process_group()
    except Exception as exc:  # one line to the command's process, no traceback here
        line = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}".rstrip(": ")
        events.put(("failed", (rank, line, exc if isinstance(exc, ShaderballError) and _picklable(exc) else None)))
        os._exit(1)  # not through the process group's teardown, which would wait for the others


def _picklable(exc: Exception) -> bool:
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return False
    return True
