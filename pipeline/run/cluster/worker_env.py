"""The environment that steers a build's workers: how many threads their Mitsuba renders use
(:func:`worker_render_threads`), drjit's kernel cache, and the GPU each is pinned to: a local
worker's (:func:`gpu_pins`, from the GPUs this process sees) and each of a batch job's workers'
(:func:`pinned_worker_commands`). No dask here."""

from __future__ import annotations

import os

from pipeline.run.cluster.options import ClusterOptions

#: Environment variable telling a worker how many threads its Mitsuba renders use.
RENDER_THREADS_ENV = "SHADERBALL_RENDER_THREADS"
#: drjit's kernel-cache location (default ``$HOME/.drjit``, shared over NFS on most clusters).
KERNEL_CACHE_ENV = "DRJIT_CACHE_DIR"
#: The shell expression of a job's GPU ids: what the batch system gives the job.
JOB_GPUS = "${CUDA_VISIBLE_DEVICES:-${SLURM_JOB_GPUS:-${SLURM_STEP_GPUS:-}}}"


def pinned_worker_commands(command: str, name: str, gpus: int) -> str:
    """dask-jobqueue's one ``dask worker --nworkers N`` line as N worker lines, worker i with
    ``CUDA_VISIBLE_DEVICES`` set to the i-th of the job's GPU ids (i itself when the batch
    system names none), named ``NAME-i`` as ``--nworkers`` would; the job waits for them all."""
    base = command.replace(f" --nworkers {gpus}", "")
    lines = [f'IFS=, read -r -a SHADERBALL_GPUS <<< "{JOB_GPUS}"']
    for i in range(gpus):
        one = base.replace(f"--name {name}", f"--name {name}-{i}") if gpus > 1 else base
        device = f'"${{SHADERBALL_GPUS[{i}]:-{i}}}"'
        lines.append(f"{PINNED_GPU_ENV}={device} {CUDA_DEVICES_ENV}={device} {one} &")
    lines.append("wait")
    return "\n".join(lines)


#: The variable that names the GPUs a CUDA process sees (and numbers them from 0).
CUDA_DEVICES_ENV = "CUDA_VISIBLE_DEVICES"
#: Set (to its device) in a worker pinned to a GPU: each shard's result names the device.
PINNED_GPU_ENV = "SHADERBALL_GPU"


def visible_gpus() -> list[str]:
    """The GPUs this process may use, as ``CUDA_VISIBLE_DEVICES`` names them: its entries when
    it is set, else ``0..n-1`` for the n devices the CUDA driver counts (none without one)."""
    listed = os.environ.get(CUDA_DEVICES_ENV)
    if listed is not None:
        return [part.strip() for part in listed.split(",") if part.strip()]
    import ctypes

    try:
        cuda = ctypes.CDLL("libcuda.so.1")
        count = ctypes.c_int(0)
        if cuda.cuInit(0) != 0 or cuda.cuDeviceGetCount(ctypes.byref(count)) != 0:
            return []
    except (OSError, AttributeError):
        return []
    return [str(i) for i in range(count.value)]


def gpu_pins(options: ClusterOptions, variant: str | None) -> list[str] | None:
    """The device of each local worker (``CUDA_VISIBLE_DEVICES`` of worker i), or None: not
    pinned (no ``--gpus`` and a variant other than cuda). ``--gpus`` N: the first N visible;
    ids: those of the visible list; ``--workers`` spreads that many workers over them."""
    cuda = bool(variant) and variant.startswith("cuda")
    if options.gpus is None and not cuda:
        return None
    visible = visible_gpus()
    if options.gpus is None:
        chosen = visible
    elif isinstance(options.gpus, int):
        if options.gpus > len(visible):
            raise ClusterOptions.field_error(
                "gpus", options.gpus, f"at most {len(visible)}", what=f"{len(visible)} GPU(s) visible here"
            )
        chosen = visible[: options.gpus]
    else:
        missing = [i for i in options.gpus if i >= len(visible)]
        if missing:
            raise ClusterOptions.field_error(
                "gpus",
                options.gpus,
                f"ids from 0 to {len(visible) - 1}" if visible else "no GPU: leave it out",
                what=f"no GPU {missing[0]} here ({len(visible)} visible)",
            )
        chosen = [visible[i] for i in options.gpus]
    if not chosen:
        return None  # cuda chosen with no device listed: nothing to pin to (resolve_variant checked it works)
    n = options.workers or len(chosen)
    return [chosen[i % len(chosen)] for i in range(n)]


# --------------------------------------------------------------------------- in the worker


def worker_render_threads() -> int:
    """Mitsuba threads for a worker that was not told: the environment, else its CPUs."""
    value = os.environ.get(RENDER_THREADS_ENV, "")
    if value.isascii() and value.isdigit() and int(value) > 0:  # "²".isdigit(), and int() refuses it
        return int(value)
    try:
        return max(1, len(os.sched_getaffinity(0)))  # the batch system's CPU set
    except AttributeError:
        return os.cpu_count() or 1
