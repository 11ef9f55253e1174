"""`shaderball bench`: one request (:class:`BenchRequest`), three benchmarks.

Without ``effects`` or ``scale``, the build benchmark (:mod:`pipeline.bench.build_bench`):
SPEC built and the same renders timed bare. ``effects``: the render time each effect the
build leaves out would cost (:mod:`pipeline.bench.effects`). ``scale``: every command's
time and memory against the dataset's size (:mod:`pipeline.bench.scale`). Each takes the
fields it uses; a field another benchmark's is refused, naming it.
"""

from __future__ import annotations

from dataclasses import dataclass

from pipeline.bench.build_bench import run_build_bench
from pipeline.bench.effects import run_effects_bench
from pipeline.bench.scale import run_scale_bench
from pipeline.dataset.spec import MAX_MATERIALS, MAX_SHARD_RENDERS, MAX_SHARDS, DatasetSection
from pipeline.dataset.spec_file import SPEC_FILE
from pipeline.fields import Checked, declared, default_of, field, same_as
from pipeline.fields.rules import Bool, Int, IntList, Optional, Path
from pipeline.render.settings import RenderSettings
from pipeline.run.cluster.options import ClusterOptions
from pipeline.store.atomic import write_text_atomic
from pipeline.store.records import dumps

#: The build benchmark's cut of the spec, in renders.
RENDERS_RANGE = (1, 1_000_000)
#: The effects benchmark's timed renders per variant.
REPEATS_RANGE = (1, 100)
#: The scale benchmark's dataset sizes, in renders.
SIZE_RANGE = (2, 10_000_000)
#: What an unset resolution and spp are in each benchmark: (resolution, spp); None: the spec's.
UNSET_SETTINGS = {"build": (None, None), "effects": (128, 64), "scale": (16, 1)}
#: The fields each benchmark takes.
TAKES = {
    "build": ("spec", "renders", "resolution", "spp", "workers", "shard_size", "out", "profile", "json_out"),
    "effects": ("effects", "resolution", "spp", "repeats", "json_out"),
    "scale": ("scale", "spec", "resolution", "spp", "out", "json_out"),
}


def _unset(index: int) -> str:
    """What an unset resolution (0) or spp (1) means, as --help says it."""
    return "the spec's; effects {}, scale {}".format(UNSET_SETTINGS["effects"][index], UNSET_SETTINGS["scale"][index])


@dataclass(frozen=True)
class BenchRequest(Checked):
    """What `shaderball bench` is asked; the render, cluster and spec fields are their
    owners' declarations."""

    spec: str | None = field(
        None,
        rule=Optional(SPEC_FILE, "unset (the effects benchmark; the scale benchmark's default)"),
        doc="The dataset spec (manifests/*.toml; docs/spec.md).",
        positional=True,
        metavar="SPEC",
    )
    renders: int | None = field(
        None,
        rule=Optional(Int(*RENDERS_RANGE), "unset (all of them)", default_text="all of them"),
        doc="Cut the spec to about this many renders (whole materials, all their lightings); the cut spec "
        f"may have at most {MAX_SHARDS} shards of its shard_size.",
        unit="renders",
    )
    resolution: int | None = same_as(RenderSettings, "resolution", unset=_unset(0))
    spp: int | None = same_as(RenderSettings, "spp", unset=_unset(1))
    workers: int | None = same_as(
        ClusterOptions, "workers", doc="The build's local dask worker processes; 0 runs in this process without dask."
    )
    shard_size: int | None = same_as(
        DatasetSection,
        "shard_size",
        unset="the spec's",
        doc="Materials per shard (the spec's dataset.shard_size); with few materials use 1 so every "
        f"worker gets a shard. A shard holds at most {MAX_SHARD_RENDERS} renders (this x the spec's "
        "lights_per_material).",
    )
    out: str | None = field(
        None,
        rule=Optional(Path("a folder"), "unset (a temporary folder)"),
        doc="Folder: the build benchmark keeps its dataset here, new or empty [default: a temporary "
        "one]; the scale benchmark writes its results page here (it needs one).",
        metavar="DIR",
    )
    profile: bool = field(
        False,
        rule=Bool(),
        doc="Also time one loaded scene per material moved in place, and moment vs plain path.",
    )
    effects: bool = field(
        False, rule=Bool(), doc="Run the effects benchmark instead: render time saved by each omitted effect."
    )
    repeats: int = field(
        5, rule=Int(*REPEATS_RANGE), doc="The effects benchmark: timed renders per variant.", unit="renders"
    )
    scale: tuple[int, ...] | None = field(
        None,
        rule=Optional(IntList(*SIZE_RANGE, distinct=True, min_len=2), "unset (no scale benchmark)"),
        doc="Run the scale benchmark instead: build datasets of these sizes (renders, e.g. "
        "1000,10000,50000) from SPEC (manifests/paper.toml if none is given), time every command over "
        "each and write README.md, scale.png and scale.json to the out folder (docs/results/scale/). Each "
        f"size's spec may have at most {MAX_MATERIALS} materials of SPEC's lightings and {MAX_SHARDS} shards.",
    )
    json_out: str | None = field(
        None, rule=Optional(Path("a file")), doc="Also write the figures to this JSON file.", metavar="FILE"
    )

    @property
    def benchmark(self) -> str:
        """Which benchmark runs: build, effects or scale."""
        return "scale" if self.scale else "effects" if self.effects else "build"

    def settings(self) -> tuple[int | None, int | None]:
        """(resolution, spp) the benchmark renders at: as given, else its own (None: the spec's)."""
        resolution, spp = UNSET_SETTINGS[self.benchmark]
        return (
            resolution if self.resolution is None else self.resolution,
            spp if self.spp is None else self.spp,
        )

    def check_cross(self) -> None:
        if self.effects and self.scale:
            raise self.field_error("scale", self.scale, "one benchmark at a time", what="not allowed with {effects}")
        benchmark, fields = self.benchmark, declared(type(self))
        takes = TAKES[benchmark]
        for name, f in fields.items():
            if name not in takes and getattr(self, name) != default_of(f):
                raise self.field_error(
                    name,
                    getattr(self, name),
                    "it takes " + ", ".join("{%s}" % n for n in takes),
                    what=f"not an option of the {benchmark} benchmark",
                )
        if benchmark == "build" and self.spec is None:
            raise self.field_error(
                "spec",
                None,
                "a spec file (e.g. manifests/smoke.toml), or {effects} for the effects benchmark",
                what="missing",
            )
        if benchmark == "scale" and self.out is None:
            raise self.field_error(
                "out", None, "a folder: the scale benchmark writes its results page there", what="missing"
            )


def run_bench(request: BenchRequest, progress=None):
    """Run the benchmark ``request`` asks for; write its figures to ``json_out`` where given;
    returns its result (``lines()``, ``to_dict()``)."""
    if request.benchmark == "scale":
        result = run_scale_bench(request, progress=progress)
    elif request.benchmark == "effects":
        resolution, spp = request.settings()
        result = run_effects_bench(resolution=resolution, spp=spp, repeats=request.repeats, progress=progress)
    else:
        result = run_build_bench(request, progress=progress)
    if request.json_out:
        write_text_atomic(request.json_out, dumps(result.to_dict()) + "\n")
    return result
