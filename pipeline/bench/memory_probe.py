"""How a render worker's resident memory grows over many renders (docs/cluster.md).

Rendering in a loop grows memory in Mitsuba (mitsuba3#1890); this probe renders N
samples in one process, shard after shard, and prints RSS as it goes:
``python -m pipeline.bench.memory_probe --memory-probe 200 --resolution 400 --spp 16``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from pipeline.dataset.plan import plan_dataset
from pipeline.dataset.spec import parse_spec
from pipeline.errors import USER_ERRORS, check_int
from pipeline.render.limits import RESOLUTION_RANGE, SPP_RANGE, span
from pipeline.run.build import prepare
from pipeline.run.shard import run_shard_in_process


def rss_mb(pid: int | str = "self") -> float:
    """Resident set size of a process, MiB (Linux /proc)."""
    with open(f"/proc/{pid}/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise OSError(f"no VmRSS for process {pid}")


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
    """Render ``renders`` samples in this process, one shard after another; track RSS."""
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m pipeline.bench.memory_probe", description="Measure a render worker's resident memory."
    )
    parser.add_argument(
        "--memory-probe",
        type=int,
        metavar="N",
        required=True,
        help="renders to run in one process (2 per material), 2 to 100000",
    )
    parser.add_argument("--resolution", type=int, default=64, help=f"pixels, {span(RESOLUTION_RANGE)} (default 64)")
    parser.add_argument("--spp", type=int, default=16, help="samples per pixel (default 16)")
    parser.add_argument("--every", type=int, default=20, help="print RSS every N renders (default 20)")
    args = parser.parse_args(argv)
    try:
        check_int("--memory-probe", args.memory_probe, 2, 100_000)
        check_int("--resolution", args.resolution, *RESOLUTION_RANGE)
        check_int("--spp", args.spp, *SPP_RANGE)

        def show(done, rss):
            if done % max(1, args.every) < 2:
                print(f"{done:6d} renders  RSS {rss:8.1f} MiB", flush=True)

        result = memory_probe(args.memory_probe, args.resolution, args.spp, progress=show)
    except USER_ERRORS as exc:
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code
    for line in result.lines():
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
