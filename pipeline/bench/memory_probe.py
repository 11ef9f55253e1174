"""How a render worker's resident memory grows over many renders (docs/cluster.md).

Rendering in a loop grows memory in Mitsuba (mitsuba3#1890); this probe renders N
samples in one process, shard after shard, and reports RSS as it goes:
``scripts/memory_probe.py --memory-probe 200 --resolution 400 --spp 16``.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from pipeline.dataset.plan import plan_dataset
from pipeline.dataset.spec_file import parse_spec
from pipeline.fields import Checked, field, same_as
from pipeline.fields.rules import Int
from pipeline.render.settings import RenderSettings
from pipeline.run.build import prepare
from pipeline.run.shard import run_shard_in_process

#: The most renders one probe runs.
MAX_PROBE_RENDERS = 100_000


def rss_mb(pid: int | str = "self") -> float:
    """Resident set size of a process, MiB (Linux /proc)."""
    with open(f"/proc/{pid}/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise OSError(f"no VmRSS for process {pid}")


@dataclass(frozen=True)
class ProbeRequest(Checked):
    """What a memory probe is asked (scripts/memory_probe.py spells ``renders`` --memory-probe)."""

    renders: int = field(
        rule=Int(2, MAX_PROBE_RENDERS), doc="Renders to run in one process (2 per material).", unit="renders"
    )
    resolution: int = same_as(RenderSettings, "resolution", default=64)
    spp: int = same_as(RenderSettings, "spp", default=16)


@dataclass
class MemoryProbe:
    renders: int
    resolution: int
    spp: int
    #: (renders done, RSS MiB) after each shard of one material.
    samples: list[tuple[int, float]]
    seconds: float

    @property
    def warm_mb(self) -> float:
        """RSS once the first 10 % of renders (kernel compilation, caches) are done."""
        cut = max(1, self.renders // 10)
        return next(rss for done, rss in self.samples if done >= cut)

    @property
    def final_mb(self) -> float:
        return self.samples[-1][1]

    @property
    def peak_mb(self) -> float:
        return max(rss for _, rss in self.samples)

    @property
    def growth_mb_per_100(self) -> float:
        cut = max(1, self.renders // 10)
        done0 = next(done for done, _ in self.samples if done >= cut)
        span = self.samples[-1][0] - done0
        return 100.0 * (self.final_mb - self.warm_mb) / span if span > 0 else 0.0

    def lines(self) -> list[str]:
        return [
            f"memory probe: {self.renders} renders at {self.resolution}x{self.resolution}, "
            f"{self.spp} spp, one process, {self.seconds:.0f} s",
            f"RSS after {max(1, self.renders // 10)} renders (warm): {self.warm_mb:.1f} MiB; "
            f"after {self.renders}: {self.final_mb:.1f} MiB; peak {self.peak_mb:.1f} MiB",
            f"growth after warm-up: {self.growth_mb_per_100:.2f} MiB per 100 renders",
        ]


def probe_spec(renders: int, resolution: int, spp: int):
    """The smoke spec with ``renders`` renders (2 per material, one material per shard)."""
    spec = parse_spec(Path(__file__).resolve().parents[2] / "manifests" / "smoke.toml")
    materials = max(1, renders // 2)
    return dataclasses.replace(
        spec,
        dataset=dataclasses.replace(
            spec.dataset, name="memory-probe", materials=materials, lights_per_material=2, shard_size=1
        ),
        render=dataclasses.replace(spec.render, resolution=resolution, spp=spp),
    )


def memory_probe(renders: int, resolution: int = 64, spp: int = 16, progress=None) -> MemoryProbe:
    """Render ``renders`` samples in this process, one shard after another; track RSS.
    ``progress(done, rss_mib)`` after each shard; the figures are refused as
    :class:`ProbeRequest` words it."""
    ProbeRequest(renders, resolution, spp)
    spec = probe_spec(renders, resolution, spp)
    plans = plan_dataset(spec)
    out = tempfile.mkdtemp(prefix="shaderball-memory-probe-")
    samples, done, start = [], 0, time.perf_counter()
    try:
        variant = prepare(out, spec, plans)
        for shard in plans:
            run_shard_in_process(out, spec, shard, variant, os.cpu_count() or 1)
            done += shard.n_renders
            samples.append((done, rss_mb()))
            if progress:
                progress(done, samples[-1][1])
    finally:
        shutil.rmtree(out, ignore_errors=True)
    return MemoryProbe(done, resolution, spp, samples, time.perf_counter() - start)
