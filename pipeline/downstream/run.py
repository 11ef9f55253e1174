"""`shaderball study --downstream`: what the network's accuracy costs in build time.

For a spec, the same samples (the spec's materials, lightings and seeds) are built at every
spp of the ladder and the spec's own (``builds/spp-N``, each a dataset `build` writes, in this
process, its CPU time measured: every thread of the process counted); the held-out samples get
references at ``reference_spp`` (two halves, re-rendered from the spec's build's records and
texture maps); the same network recipe (``training``) is trained on each level with
``repeats`` seeds and one held-out set (train's split with ``--split-seed`` SPLIT_SEED: the
same materials for every run), and every network is scored against the references, never
against its own noisy targets. The spec's level is trained with ``repeats`` more seeds: the
A/A row, what "no difference" looks like. The first loss is trained at every level; each
other loss at the spec's level and at the cheapest level the first passes (the cheapest
level where none passes). pipeline.downstream.report compares and decides.

Builds run in ascending spp: the first build in a process also compiles Mitsuba's kernels,
which lands on the cheapest level (against the cheap levels: conservative).

Resumable: every build, reference, run and score is kept in the study folder as it is made, a
re-run of the same command finishes the rest (builds and runs resume themselves), and a
folder holding another request is refused. The same study twice gives the same figures but
for the timings (seeds fixed; Mitsuba's LLVM variant and torch on the CPU are deterministic).
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from dataclasses import dataclass

import numpy as np

from pipeline.downstream import report
from pipeline.downstream.plan import (
    SCORING_SHARE,
    estimate_line,
    level_spec,
    render_seconds,
    training_rate,
    warm_up,
    write_spec,
)
from pipeline.downstream.request import StudyCommandRequest
from pipeline.downstream.score import ensure_references, mean_image_rows, score_run, target_rows
from pipeline.fields.rules import Reject
from pipeline.image import metrics
from pipeline.neural.config import NetworkResolution, TrainConfig
from pipeline.neural.data import open_dataset
from pipeline.neural.evaluate import dataset_variant
from pipeline.neural.runfiles import read_config, read_log
from pipeline.neural.splits import split_materials
from pipeline.neural.train import train
from pipeline.run.build import build
from pipeline.run.cluster.options import ClusterOptions
from pipeline.store.atomic import write_text_atomic
from pipeline.study.request import REQUEST_FILE, check_request, check_resumable, request_record

#: The held-out split of every run (train's --split-seed): one held-out set for all.
SPLIT_SEED = 0


@dataclass(frozen=True)
class Run:
    """One network of the study: its loss, level (spp) and training seed."""

    loss: str
    spp: int
    seed: int

    @property
    def name(self) -> str:
        return f"{self.loss}-spp{self.spp}-seed{self.seed}"


@dataclass
class DownstreamSummary:
    out: str
    levels: list[int]
    runs: int
    seconds: float
    decision: dict

    def lines(self) -> list[str]:
        return [
            f"downstream study: {len(self.levels)} levels ({', '.join(map(str, self.levels))} spp), {self.runs} networks, "
            f"{self.seconds:.0f} s",
            f"wrote {self.out}/downstream.json, report.md, downstream.png",
            self.decision.get("verdict", ""),
        ]

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


class Clock:
    """The study's steps, each weighted by its estimated seconds; progress lines carry an ETA:
    the estimate of what is left, scaled by how long the steps of its kind (``build``/
    ``references``: rendering; ``run``: training) took against their estimates so far."""

    def __init__(self, weights: dict[str, float], progress):
        self.left, self.progress = dict(weights), progress
        self.count, self.steps, self.started = 0, len(weights), time.perf_counter()
        self.measured: dict[str, list[float]] = {"render": [0.0, 0.0], "train": [0.0, 0.0]}  # [estimated, taken]

    @staticmethod
    def kind(key: str) -> str:
        return "train" if key.startswith("run ") else "render"

    def add(self, key: str, seconds: float) -> None:
        self.left[key] = seconds
        self.steps += 1

    def step(self, key: str, what: str, seconds: float | None = None) -> None:
        """Step ``key`` is done (``seconds``: what it took now; None: kept from an earlier run)."""
        weight = self.left.pop(key, 0.0)
        self.count += 1
        if seconds is not None and weight > 0:
            pair = self.measured[self.kind(key)]
            pair[0] += weight
            pair[1] += seconds
        if self.progress is None:
            return
        eta = 0.0
        for key_left, w in self.left.items():
            estimated, taken = self.measured[self.kind(key_left)]
            eta += w * (taken / estimated if estimated > 0 else 1.0)
        self.progress(
            {
                "done": self.count,
                "total": self.steps,
                "what": what,
                "elapsed_s": time.perf_counter() - self.started,
                "eta_s": eta,
            }
        )

    def note(self, text: str) -> None:
        if self.progress is not None:
            self.progress({"note": text})


def run_downstream(req: StudyCommandRequest, progress=None, command: str = "") -> DownstreamSummary:
    """Run (or resume) a downstream study; see the module's docstring."""
    started = time.perf_counter()
    spec = check_request(req)
    resolution = req.resolution or spec.render.resolution
    _check_spec(req, spec, resolution)
    levels = sorted({*req.ladder, spec.render.spp})
    record = {**request_record(req, spec), "downstream": True, "training": req.training.to_dict()}
    check_resumable(req, record)
    os.makedirs(req.out, exist_ok=True)
    write_text_atomic(os.path.join(req.out, REQUEST_FILE), json.dumps(record, indent=1) + "\n")
    first, others = req.training.losses[0], req.training.losses[1:]
    runs = _first_runs(first, levels, spec.render.spp, req.repeats)
    clock, per_run = _plan(req, spec, levels, resolution, runs, progress)
    builds = {spp: _ensure_build(req, spec, spp, resolution, clock) for spp in levels}
    spec_root = builds[spec.render.spp]["root"]
    source = open_dataset(spec_root, resolution=resolution)
    variant = dataset_variant(source)
    for b in builds.values():  # what the decision compares: CPU time, or wall time where the GPU renders
        b["build_cost"] = b["build_cpu" if report.cost_basis(variant) == "CPU" else "build_wall"]
    train_ids, test_ids = split_materials(
        [s.material_id for s in source.samples], req.training.test_fraction, SPLIT_SEED
    )
    started_refs = time.perf_counter()
    held = source.subset(test_ids)
    references = ensure_references(
        os.path.join(req.out, "references"), held, req.reference_spp, _every_tenth(clock, len(held))
    )
    clock.step(
        "references", f"{len(references)} references at {req.reference_spp} spp", time.perf_counter() - started_refs
    )
    flip = req.flip and metrics.flip_available()
    os.makedirs(os.path.join(req.out, "scores"), exist_ok=True)
    for spp, b in builds.items():  # the noise each level's targets carry, against the same references
        rows = target_rows(
            b["root"], test_ids, resolution, references, os.path.join(req.out, "scores", f"targets-spp{spp}.json")
        )
        b["targets_relmse_ball"] = float(np.mean([r["relmse_ball"] for r in rows]))
        b["targets_bias_ball"] = float(np.mean([r["bias_ball"] for r in rows]))
    scored = {}
    for run in runs:
        scored[run] = _train_and_score(req, run, builds, resolution, test_ids, references, flip, clock)
    baseline = mean_image_rows(
        spec_root, train_ids, test_ids, resolution, references, flip, os.path.join(req.out, "scores", "mean-image.json")
    )
    first_result = report.compare_levels(scored, first, levels, spec.render.spp, req.repeats, builds)
    for loss in others:
        # the cheapest passing level; where none cheaper than the spec's passes, the cheapest level
        cheap = first_result["cheapest"] if first_result["cheapest"] != spec.render.spp else levels[0]
        for spp in sorted({spec.render.spp, cheap}):
            for seed in range(req.repeats):
                run = Run(loss, spp, seed)
                clock.add(f"run {run.name}", per_run)
                scored[run] = _train_and_score(req, run, builds, resolution, test_ids, references, flip, clock)
    args = (levels, scored, builds, references, baseline, test_ids, train_ids, flip, command, variant)
    result = report.results(req, spec, *args)
    report.write(req.out, result)
    return DownstreamSummary(req.out, levels, len(scored), time.perf_counter() - started, result["decision"])


def _plan(req: StudyCommandRequest, spec, levels: list[int], resolution: int, runs: list[Run], progress):
    """Print the plan and its estimate (after the warm-up and the probes); the clock of the
    steps and the estimated seconds of one network."""
    held = _held_materials(spec, req) * spec.dataset.lights_per_material
    first, others = req.training.losses[0], req.training.losses[1:]
    renders = spec.dataset.materials * spec.dataset.lights_per_material
    train_samples = renders - held
    extra = len(others) * 2 * req.repeats
    note = progress or (lambda p: None)
    then = (
        f", then up to {extra} more ({', '.join(others)}: the spec's level and the cheapest passing)" if others else ""
    )
    note(
        {
            "note": f"plan: {len(levels)} builds of {renders} renders ({', '.join(map(str, levels))} spp; the spec's "
            f"{spec.render.spp}) at {resolution} px; references of the {held} held-out samples at {req.reference_spp} spp "
            f"(two halves); {len(runs)} networks ({first}: {len(levels)} levels x {req.repeats} seeds + {req.repeats} A/A "
            f"seeds at {spec.render.spp} spp) of {req.training.epochs} epochs on {train_samples} samples{then}"
        }
    )
    note({"note": "measuring: each level's kernels compiled (a small build each), render and training rates"})
    per_render, rate = warm_up(req.out, spec, levels, resolution), training_rate(req, resolution)
    line, _ = estimate_line(req, levels, renders, held, len(runs) + extra, per_render, rate)
    note({"note": line})
    # Weights: each step's estimated seconds; the ETA scales them by what the steps took.
    weights = {f"build {spp}": renders * render_seconds(per_render, spp) for spp in levels}
    weights["references"] = held * 2 * render_seconds(per_render, req.reference_spp // 2)
    per_run = req.training.epochs * train_samples / rate * (1 + SCORING_SHARE)
    weights.update({f"run {r.name}": per_run for r in runs})
    return Clock(weights, progress), per_run


def _check_spec(req: StudyCommandRequest, spec, resolution: int) -> None:
    """What the downstream study needs of the spec: texture maps (the references are rendered
    from them) and a resolution the network takes."""
    if not spec.storage.texture_maps:
        raise req.field_error(
            "spec",
            req.spec,
            "a spec whose storage.texture_maps is true (the references are rendered from the stored texture maps)",
            what=f"{req.spec} stores no texture maps",
        )
    try:
        NetworkResolution().check(resolution)
    except Reject:
        raise req.field_error(
            "resolution",
            resolution,
            "a multiple of 16 from 16 to 4096 with {downstream} (the networks train at it): give {resolution}",
            what=f"the spec's render.resolution {resolution} is not a resolution the network takes",
        ) from None


def _held_materials(spec, req: StudyCommandRequest) -> int:
    """How many materials the split holds out (train's rule, pipeline.neural.splits)."""
    n = spec.dataset.materials
    if n < 2:
        raise req.field_error("spec", req.spec, "a spec of 2 or more materials (some are held out)")
    return min(max(1, round(req.training.test_fraction * n)), n - 1)


def _first_runs(loss: str, levels: list[int], spec_spp: int, repeats: int) -> list[Run]:
    """The first loss at every level, ``repeats`` seeds each, and the A/A seeds at the spec's."""
    runs = [Run(loss, spp, seed) for spp in levels for seed in range(repeats)]
    return runs + [Run(loss, spec_spp, seed) for seed in range(repeats, 2 * repeats)]


def _ensure_build(req: StudyCommandRequest, spec, spp: int, resolution: int, clock: Clock) -> dict:
    """The build of level ``spp`` (made or resumed) and its CPU time: of every call that
    rendered, scaled to the whole build from its renders (a killed call's part is re-timed
    by the renders made since)."""
    spec_path = write_spec(os.path.join(req.out, "specs"), f"spp-{spp}.toml", level_spec(spec, spp, resolution))
    root = os.path.join(req.out, "builds", f"spp-{spp}")
    timing_path = root + ".time.json"
    attempts = _read_json(timing_path, [])
    cpu0, wall0 = time.process_time(), time.perf_counter()
    summary = build(spec_path, root, cluster=ClusterOptions(workers=0))
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    if summary.rendered:
        attempts.append({"cpu_s": cpu, "wall_s": wall, "rendered": summary.rendered})
        write_text_atomic(timing_path, json.dumps(attempts, indent=1) + "\n")
    rendered = sum(a["rendered"] for a in attempts)
    scale = summary.total / rendered if rendered else None
    clock.step(f"build {spp}", f"build at {spp} spp: {summary.total} renders", wall if summary.rendered else None)
    return {
        "root": root,
        "renders": summary.total,
        "build_cpu": scale * sum(a["cpu_s"] for a in attempts) if scale else None,
        "build_wall": scale * sum(a["wall_s"] for a in attempts) if scale else None,
    }


def _train_and_score(req, run: Run, builds, resolution, test_ids, references, flip, clock) -> dict:
    """A run trained (or resumed, or kept) and scored against the references."""
    run_dir = os.path.join(req.out, "runs", run.name)
    t = req.training
    config = TrainConfig(
        dataset=builds[run.spp]["root"],
        out=run_dir,
        epochs=t.epochs,
        batch_size=t.batch_size,
        width=t.width,
        schedule=t.schedule,
        test_fraction=t.test_fraction,
        seed=run.seed,
        split_seed=SPLIT_SEED,
        resolution=resolution,
        loss=run.loss,
    )
    started = time.perf_counter()
    summary = train(config, progress=_epoch_lines(clock, run))
    if read_config(run_dir)["split"]["test"] != list(test_ids):
        raise RuntimeError(f"{run_dir}: its held-out split is not the study's")  # train's split rule changed
    rows = score_run(
        run_dir,
        builds[run.spp]["root"],
        test_ids,
        references,
        flip,
        os.path.join(req.out, "scores", f"{run.name}.json"),
    )
    trained = not summary.nothing_to_do
    clock.step(f"run {run.name}", f"network {run.name}", time.perf_counter() - started if trained else None)
    return {"rows": rows, "train_s": sum(float(e.get("time_s") or 0.0) for e in read_log(run_dir))}


def _every_tenth(clock: Clock, total: int):
    """A note at every tenth of the references (they take minutes)."""
    count = [0]

    def tick(what: str) -> None:
        count[0] += 1
        if count[0] == total or count[0] % max(1, total // 10) == 0:
            clock.note(f"  references: {count[0]}/{total} ({what})")

    return tick


def _epoch_lines(clock: Clock, run: Run):
    """train's progress, one note per finished epoch (its batches stay quiet)."""

    def show(p: dict) -> None:
        if "epoch" in p and p["batch"] == p["batches"]:
            clock.note(f"  {run.name}: epoch {p['epoch']}/{p['epochs']}, loss {p['loss']:.4f}")

    return show


def _read_json(path: str, default):
    try:
        with open(path, encoding="utf-8") as fh:
            return json.load(fh)
    except FileNotFoundError:
        return default
