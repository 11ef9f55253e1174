"""The downstream study's plan and estimate, printed before it starts, and its warm-up.

**Warm-up and probe.** Each level's kernels are compiled before its timed build by a build of
the spec's first PROBE_MATERIALS materials at that level's spp (a throwaway folder), so the
compilation is kept out of the build CPU times; the lowest and the highest levels are built so
once more, timed, for the estimate's render cost per render (a line through the two spp). The
networks' rate is measured on random batches (pipeline.neural.bench's training steps) with the
study's network, loss and batch size. The estimate then adds up builds, references and runs;
the progress lines' ETA follows what is measured as the study runs.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import time

from pipeline.dataset.spec_file import spec_to_toml
from pipeline.downstream.request import StudyCommandRequest
from pipeline.neural import speed
from pipeline.neural.bench import TrainingSteps
from pipeline.neural.config import TrainConfig
from pipeline.neural.train import pick_device
from pipeline.run.build import build
from pipeline.run.cluster.options import ClusterOptions
from pipeline.store.atomic import write_text_atomic

#: Materials of a warm-up build (uniform and SVBRDF ones among them: their kernels differ).
PROBE_MATERIALS = 4
#: Timed training steps of the rate probe (after one untimed).
PROBE_STEPS = 3
#: Held-out scoring after each epoch, on top of the steps (measured: about a tenth).
SCORING_SHARE = 0.15


def level_spec(spec, spp: int, resolution: int, materials: int | None = None):
    """``spec`` at another spp and resolution (and, for a probe, fewer materials)."""
    out = dataclasses.replace(spec, render=dataclasses.replace(spec.render, spp=spp, resolution=resolution))
    if materials is not None:
        out = dataclasses.replace(out, dataset=dataclasses.replace(out.dataset, materials=materials))
    return out


def write_spec(folder: str, name: str, spec) -> str:
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, name)
    write_text_atomic(path, spec_to_toml(spec))
    return path


def warm_up(out: str, spec, levels: list[int], resolution: int) -> dict[int, float]:
    """Compile every level's kernels (a probe build each); {spp: CPU seconds per render} of
    the lowest and highest levels built once more, warm. Leaves nothing behind."""
    folder = os.path.join(out, "warm-up")
    materials = min(PROBE_MATERIALS, spec.dataset.materials)
    per_render = {}
    try:
        for spp in levels:
            probe = write_spec(folder, f"spp-{spp}.toml", level_spec(spec, spp, resolution, materials))
            root = os.path.join(folder, f"spp-{spp}")
            build(probe, root, cluster=ClusterOptions(workers=0))
            if spp in (levels[0], levels[-1]):
                shutil.rmtree(root)
                started = time.process_time()
                summary = build(probe, root, cluster=ClusterOptions(workers=0))
                per_render[spp] = (time.process_time() - started) / max(1, summary.total)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return per_render


def render_seconds(per_render: dict[int, float], spp: int) -> float:
    """CPU seconds of one render at ``spp`` on the line through the probe's two points (no
    fixed part below 0, no cost per spp below 0)."""
    (s0, t0), (s1, t1) = sorted(per_render.items())[0], sorted(per_render.items())[-1]
    slope = max(0.0, (t1 - t0) / (s1 - s0)) if s1 != s0 else t1 / s1
    fixed = max(0.0, t0 - slope * s0)
    return fixed + slope * spp


def training_rate(req: StudyCommandRequest, resolution: int) -> float:
    """Training samples per second of the study's network on random batches, on this machine."""
    config = TrainConfig(
        dataset="",
        benchmark=True,
        width=req.training.width,
        batch_size=req.training.batch_size,
        loss=req.training.losses[0],
        resolution=resolution,
    )
    device = pick_device(config.device)
    config = dataclasses.replace(config, precision=speed.resolve_precision(config.precision, device))
    return TrainingSteps(config, device, resolution).samples_per_s(PROBE_STEPS)


def estimate_line(req, levels, renders: int, held: int, runs: int, per_render, rate: float) -> tuple[str, float]:
    """(the estimate's line, its seconds): builds, references and runs on this machine."""
    builds = sum(renders * render_seconds(per_render, spp) for spp in levels)
    references = held * 2 * render_seconds(per_render, req.reference_spp // 2)
    per_run = req.training.epochs * (renders - held) / rate * (1 + SCORING_SHARE)
    total = builds + references + runs * per_run
    return (
        f"estimate: {_minutes(total)} on this machine: builds {_minutes(builds)} (CPU), references "
        f"{_minutes(references)} (CPU), {runs} networks x {_minutes(per_run)} ({rate:.1f} training samples/s)",
        total,
    )


def _minutes(seconds: float) -> str:
    return f"{seconds / 60:.1f} min" if seconds >= 60 else f"{seconds:.0f} s"
