"""shaderball's command line: a thin click face over the library.

Each command parses its options, calls one library function, prints a short
summary and maps the project's own error (:class:`pipeline.errors.ShaderballError`)
to a message on stderr and exit code 2. Logic lives in the packages.
"""

# ruff: noqa: E402 - the imports come after the Ctrl-C handler that covers them

from __future__ import annotations

import os
import signal
import sys

from pipeline.ui.process import stop_on_ctrl_c_while_loading

if __name__ == "__main__":  # `python -m cli`; Python's own handler is back before main() runs
    stop_on_ctrl_c_while_loading()

import dataclasses
import functools

import click

from pipeline.bench.build_bench import run_from_args
from pipeline.bench.effects import REPEATS_RANGE
from pipeline.bench.estimate import PlanRequest, plan_spec
from pipeline.bench.scale import SIZE_RANGE as SCALE_SIZE_RANGE
from pipeline.bench.scale import run_scale_bench
from pipeline.check.info import dataset_info
from pipeline.check.preview import SAMPLES_RANGE, TILE_RANGE, write_preview
from pipeline.check.validate import validate
from pipeline.dataset.spec import MAX_MATERIALS
from pipeline.errors import ShaderballError
from pipeline.neural.config import TrainConfig
from pipeline.neural.limits import DEVICES, SPP_LADDER_RANGE
from pipeline.publish.facts import LICENSES
from pipeline.publish.unpack import unpack
from pipeline.publish.verify import verify
from pipeline.publish.writer import DEFAULT_LICENSE, DEFAULT_SHARD_BYTES, SHARD_BYTES_RANGE, publish
from pipeline.render.command import RenderRequest, render_to_files
from pipeline.render.limits import SPP_RANGE, span
from pipeline.render.scene_command import write_scene
from pipeline.render.settings import RenderSettings
from pipeline.run.build import build
from pipeline.run.cluster.connection import job_script
from pipeline.run.cluster.options import (
    ClusterOptions,
)
from pipeline.run.repair import repair
from pipeline.serve.command import ServeOptions, serve_command
from pipeline.study.configs import DEFAULT_LADDER
from pipeline.study.run import (
    MAX_LADDER_SPP,
    StudyRequest,
    parse_families,
    parse_ladder,
    run_study,
)
from pipeline.ui import command as ui_command
from pipeline.ui import process
from pipeline.ui.command import Command, Group
from pipeline.ui.options import option_from, options_from
from pipeline.ui.progress import (
    build_progress,
    evaluate_progress,
    say,
    study_progress,
    training_progress,
    validate_progress,
)
from pipeline.ui.values import parse_int_list

INTERNAL_EXIT = process.INTERNAL_EXIT
_emit_json = process.emit_json


def _friendly_errors(func):
    """The command's body run by :func:`pipeline.ui.process.run_command`."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        process.run_command(lambda: func(*args, **kwargs), bool(kwargs.get("as_json")))

    return wrapper


_Command = Command


def json_option(help: str):
    """``--json``, a flag (transitional decorator; generated commands get it from their request)."""
    param = ui_command.json_option(help)
    return lambda func: (click.decorators._param_memo(func, param), func)[1]


def renamed_option(old: str, new: str, why: str = "", *, takes_value: bool = True):
    param = ui_command.renamed_option(old, new, why, takes_value=takes_value)
    return lambda func: (click.decorators._param_memo(func, param), func)[1]


_Group = Group


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(package_name="shaderball")
def main():
    """Build, validate and train from datasets of path-traced material renders on a shaderball.

    Every sample pairs four screen-space material maps (diffuse, specular, roughness,
    normal) and a lighting vector (sun direction, turbidity) with a Mitsuba 3 path-traced
    render of the shaderball under a Hosek-Wilkie sun and sky.

    \b
    Examples:
      shaderball build manifests/smoke.toml --out demo-out/smoke
      shaderball train demo-out/smoke --out runs/smoke --epochs 1
    """


# Option groups, declared once: every command that takes one of these uses the same declaration.


def _options(*options):
    """One decorator of several click options, applied in the order given (as --help lists them)."""

    def apply(func):
        for option in reversed(options):
            func = option(func)
        return func

    return apply


def json_file_option(help: str):
    """``--json-out FILE`` (``json_path``): also write the figures to a JSON file."""
    return click.option("--json-out", "json_path", type=click.Path(dir_okay=False), default=None, help=help)


def out_option(help: str, *, folder: bool, required: bool = True, dest: str = "out"):
    """``--out``: a folder (``folder=True``) or a file the command writes."""
    kind = click.Path(file_okay=False) if folder else click.Path(dir_okay=False)
    return click.option("--out", dest, required=required, type=kind, default=None, help=help)


def variant_option():
    return option_from(
        RenderSettings, "variant", help="Mitsuba backend: auto picks cuda when a GPU works, else llvm (the CPU)."
    )


def resolution_option():
    return option_from(RenderSettings, "resolution")


def device_option(help: str = "Where the network runs: auto (cuda when torch sees a GPU, else cpu), cpu or cuda."):
    """torch's device (infer, evaluate)."""
    return click.option("--device", default="auto", show_default=True, type=click.Choice(DEVICES), help=help)


def material_options():
    """The uniform material (--diffuse, --specular, --roughness, --normal) or --svbrdf maps, of
    `render` and `infer`: RenderRequest's declarations."""
    return options_from(RenderRequest, "diffuse", "specular", "roughness", "normal", "svbrdf", "svbrdf_colorspace")


def light_options():
    """The sun and sky (--elevation, --azimuth, --turbidity) of `render` and `infer`."""
    return options_from(RenderRequest, "elevation_deg", "azimuth_deg", "turbidity")


@main.command("scene")
@out_option(
    "Output folder; created if missing. Receives shaderball.ply, gbuffer.exr, preview.png.", folder=True, dest="out_dir"
)
@resolution_option()
@variant_option()
@json_option("Print what was written (files, mesh and atlas figures, times) as JSON on stdout.")
@_friendly_errors
def scene_cmd(out_dir: str, resolution: int, variant: str, as_json: bool):
    """Write the shaderball mesh, its G-buffer and a preview picture.

    \b
    Example:
      shaderball scene --out demo-out/scene --resolution 64
    """

    _print_result(write_scene(out_dir, resolution=resolution, variant=variant), as_json)


@main.command("render")
@material_options()
@light_options()
@options_from(
    RenderRequest,
    *("spp", "resolution", "max_depth", "seed", "variant", "sun", "model"),
    variant={"help": "Mitsuba backend: auto picks cuda when a GPU works, else llvm (the CPU)."},
    sun={
        "help": "split: delta sun + sky-only sunsky (measured default, docs/sky.md); sunsky: the sun disk inside sunsky."
    },
    model={
        "help": "Material model: shaderball (GGX as published, energy-conserving) or deschaintre2018 "
        "(Deschaintre et al.'s code, with its floors on GGX D and Smith G1; darker below "
        "roughness 0.178; docs/materials.md). A spec's materials.model."
    },
)
@out_option("Output EXR file: layers render.R/G/B (float32) and the screen-space maps.", folder=False)
@click.option("--png", type=click.Path(dir_okay=False), default=None, help="Also write a tone-mapped PNG for people.")
@json_option("Print what was written (files, render statistics and time, lighting, effects) as JSON on stdout.")
@_friendly_errors
def render_cmd(as_json, **options):
    """Render one material on the shaderball under one sun and sky.

    \b
    Example:
      shaderball render --out demo-out/ball.exr --png demo-out/ball.png --resolution 64 --spp 16 --elevation 30
    """

    request = RenderRequest(**options)
    _print_result(render_to_files(request), as_json)


@main.command("build")
@click.argument("spec", type=click.Path(dir_okay=False))
@out_option(
    "Dataset folder. Created if missing; an existing one built from the same spec is "
    "resumed (only missing or unverified samples are rendered); another spec is refused.",
    folder=True,
)
@options_from(
    ClusterOptions, "workers", "scheduler", workers={"unset": "one per 2 cores"}, scheduler={"metavar": "ADDRESS"}
)
@click.option(
    "--allow-spec-change",
    is_flag=True,
    help="Accept a spec that differs from DIR/spec.toml in dataset.name or dataset.version only "
    "(no sample depends on them); any other difference is refused.",
)
@options_from(
    ClusterOptions,
    *("kind", "jobs", "cores", "memory", "walltime", "queue", "account", "scratch", "recycle_after", "start_timeout"),
    memory={"metavar": "SIZE"},
    walltime={"metavar": "HH:MM:SS"},
    scratch={"metavar": "DIR"},
    recycle_after={"metavar": "RENDERS"},
    start_timeout={"metavar": "SECONDS"},
)
@click.option(
    "--print-job-script",
    is_flag=True,
    help="slurm/pbs: print the batch script each job would run, then exit; nothing is submitted or written.",
)
@json_option("Print what was built (folder, manifest, counts, seconds) as JSON on stdout; progress stays on stderr.")
@_friendly_errors
def build_cmd(spec, out, allow_spec_change, print_job_script, as_json, **cluster):
    """Build (or resume) a dataset of renders from a spec (see manifests/ and docs/spec.md).

    Clusters, SLURM/PBS and worker memory: docs/cluster.md. Resume and crash safety: docs/resume.md.

    \b
    Example:
      shaderball build manifests/smoke.toml --out demo-out/smoke
    """

    options = ClusterOptions(**cluster).check()
    if print_job_script:
        if not options.is_jobqueue:
            raise click.UsageError("--print-job-script needs --cluster slurm or --cluster pbs")
        click.echo(job_script(options), nl=False)
        return

    def started(where, dashboard):
        click.echo(f"building with {where}" + (f"; dashboard {dashboard}" if dashboard else ""), err=True)

    summary = build(
        spec, out, cluster=options, allow_spec_change=allow_spec_change, progress=build_progress(), on_start=started
    )
    _print_result(summary, as_json, manifest=os.path.join(summary.out, "manifest.jsonl"))


@main.command("validate")
@click.argument("directory", metavar="DIR", type=click.Path())
@json_option(
    "Print the report as JSON on stdout: expected/present/valid render counts and "
    "problems [{kind, id, path, message}] (docs/validate.md)."
)
@click.option(
    "--repair",
    "fix",
    is_flag=True,
    help="Fix what is bad (delete extra files, regenerate or re-render bad files and records, "
    "rewrite the manifest), then validate again. Renders are deterministic: repaired "
    "files are byte-identical to the originals.",
)
@click.option(
    "--fast", is_flag=True, help="Check sizes, markers and records only; read no file (no SHA-256, no decoding)."
)
@options_from(
    ClusterOptions,
    "workers",
    workers={
        "default": 0,
        "show_default": True,
        "help": "With --repair: local dask worker processes for re-rendering; 0 renders in this process.",
    },
)
@click.option(
    "--spec",
    "spec_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="With --repair: restore an unreadable or edited DIR/spec.toml from this spec, "
    "if its digest is the one dataset.json records.",
)
@_friendly_errors
def validate_cmd(directory, as_json, fix, fast, workers, spec_path):
    """Check a dataset against its manifest, its plan and itself; exit 0 if valid, 1 if not.

    Every file against the manifest (exists, size, SHA-256, decodes, layers), every value
    for sanity (finite, in range, unit normals, non-negative renders, statistics), the
    whole against the plan (nothing missing, extra or duplicated; spec snapshot intact).
    Progress goes to stderr.

    \b
    Examples:
      shaderball validate demo-out/smoke
      shaderball validate demo-out/smoke --fast --json
    """
    if fast and fix:
        raise click.UsageError("--fast and --repair cannot be combined: a repair needs the full check")
    if spec_path and not fix:
        raise click.UsageError("--spec is used only with --repair")
    show = validate_progress()
    if fix:
        before, report, actions = repair(directory, workers=workers, progress=show, spec_path=spec_path)
    else:
        before, report, actions = None, validate(directory, fast=fast, progress=show), []
    if as_json:
        out = report.to_dict()
        out["exit"] = 0 if report.ok else 1
        if fix:
            out["repair"] = {"before": before.to_dict(), "actions": [a.to_dict() for a in actions]}
        _emit_json(out)
    else:
        if fix:
            click.echo(f"before repair: {len(before.problems)} problem(s); {len(actions)} action(s)")
            for action in actions:
                click.echo(f"  {action.action}: {action.message}")
        for line in report.lines():
            click.echo(line)
    sys.exit(0 if report.ok else 1)


@main.command("preview")
@click.argument("directory", metavar="DIR", type=click.Path())
@out_option(
    "PNG file to write: one row per sample, its tone-mapped render beside its four maps, "
    "labelled with its id, material and lighting.",
    folder=False,
)
@click.option(
    "--limit",
    default=8,
    show_default=True,
    type=int,
    help=f"Rows, {span(SAMPLES_RANGE)}: this many samples, spread evenly over the renders recorded so far.",
)
@renamed_option("--samples", "--limit")
@click.option(
    "--tile",
    default=None,
    type=int,
    help=f"Picture size in pixels, {span(TILE_RANGE)} [default: the render size, scaled to 128-256].",
)
@json_option("Print what was written (the picture, its samples, what was left out) as JSON on stdout.")
@_friendly_errors
def preview_cmd(directory, out, limit, tile, as_json):
    """A contact sheet of a dataset (complete or partial) for people to look at.

    \b
    Example:
      shaderball preview demo-out/smoke --out demo-out/smoke-preview.png
    """

    _print_result(write_preview(directory, out, samples=limit, tile=tile), as_json)


@main.command("info")
@click.argument("directory", metavar="DIR|SPEC", type=click.Path())
@json_option("Print the figures as JSON instead.")
@_friendly_errors
def info_cmd(directory, as_json):
    """Counts, sizes, spec summary and completion of a dataset folder (works on partial builds).

    Given a spec file instead: what `shaderball plan SPEC` prints without timing (counts, shards, disk).

    \b
    Examples:
      shaderball info demo-out/smoke
      shaderball info manifests/paper.toml
    """

    if os.path.isfile(directory):
        info = plan_spec(PlanRequest(spec=directory, timed=False))
    else:
        info = dataset_info(directory)
    if as_json:
        _emit_json(info.to_dict())
        return
    for line in info.lines():
        click.echo(line)


@main.command("plan")
@click.argument("spec", type=click.Path(dir_okay=False))
@options_from(PlanRequest, "samples")
@renamed_option("--samples", "--limit")
@click.option("--no-timing", is_flag=True, help="Counts and disk only; render nothing (what `info SPEC` prints).")
@options_from(
    PlanRequest,
    "cluster",
    "workers",
    "jobs",
    "cores",
    cluster={
        "help": "Also estimate the time on batch jobs (with --jobs and --cores), as `build --cluster` would run them."
    },
    workers={"unset": "one per 2 cores, as build"},
)
@json_option("Print the plan as JSON on stdout.")
@_friendly_errors
def plan_cmd(spec, no_timing, as_json, **options):
    """What building SPEC takes, before building it: renders, materials, lightings, shards, disk, time.

    The time comes from the spec's own first renders, built here at the spec's settings
    (seconds to minutes; nothing is kept), extrapolated per worker (docs/build.md).

    \b
    Examples:
      shaderball plan manifests/smoke.toml
      shaderball plan manifests/smoke.toml --cluster slurm --jobs 8 --cores 32
    """
    request = PlanRequest(spec=spec, timed=not no_timing, **options)
    report = plan_spec(request, progress=say)
    if as_json:
        _emit_json(report.to_dict())
        return
    for line in report.lines():
        click.echo(line)


@main.command("study")
@click.argument("spec", type=click.Path(dir_okay=False))
@out_option(
    "Study folder: request.json, references/, rows/, then study.json, study.csv, pareto.png, "
    "report.md. Re-running the same command resumes; another request is refused.",
    folder=True,
)
@options_from(StudyRequest, "samples", "reference_spp", "resolution")
@renamed_option("--samples", "--draws")
@click.option(
    "--ladder",
    default=",".join(map(str, DEFAULT_LADDER)),
    show_default=True,
    help=f"spp ladder of the independent sampler, comma-separated, {span((1, MAX_LADDER_SPP))} (the spec's spp is always added).",
)
@click.option(
    "--configs",
    "families",
    default="all",
    show_default=True,
    help="Families of configurations: all, or comma-separated from ladder, denoise, samplers, passes, depth, "
    "rr, sun, clamp, robust, adaptive (the ladder is always measured).",
)
@click.option(
    "--only",
    default="",
    metavar="NAMES",
    help="Only these configurations (comma-separated names as the report writes them, e.g. "
    "multijitter/64); the spec's recipe is always measured.",
)
@options_from(StudyRequest, "repeats", "flip", flip={"flag": "--flip/--no-flip"})
@json_option("Print the summary as JSON on stdout (progress stays on stderr).")
@_friendly_errors
def study_cmd(spec, out, ladder, families, only, as_json, **options):
    """What accuracy costs in time: error-vs-time of render recipes against references (docs/accuracy.md).

    \b
    Example:
      shaderball study manifests/smoke.toml --out demo-out/smoke-study --resolution 16 \\
        --configs ladder --ladder 4 --reference-spp 64 --repeats 1 --no-flip
    """

    req = StudyRequest(
        spec=spec,
        out=out,
        ladder=parse_ladder(ladder),
        families=parse_families(families),
        only=tuple(n for n in only.split(",") if n),
        **options,
    )
    summary = run_study(req, progress=study_progress)
    if as_json:
        _emit_json(summary.to_dict())
        return
    for line in summary.lines():
        click.echo(line)


@main.command("bench")
@click.argument("spec", required=False, type=click.Path(dir_okay=False))
@click.option(
    "--limit",
    type=int,
    default=None,
    help="Cut the spec to about this many renders (whole materials, all their lightings) [default: all of them].",
)
@renamed_option("--samples", "--limit")
@options_from(
    RenderSettings,
    "resolution",
    "spp",
    resolution={"unset": "the spec's; with --effects 128"},
    spp={"unset": "the spec's; with --effects 64"},
)
@options_from(ClusterOptions, "workers", workers={"unset": "the build's"})
@click.option(
    "--shard-size",
    type=int,
    default=None,
    help=f"Materials per shard, {span((1, MAX_MATERIALS))} [default: the spec's]; with few materials use 1 so "
    "every worker gets a shard.",
)
@out_option(
    "Keep the benchmark's dataset in this new or empty folder [default: a temporary one].", folder=True, required=False
)
@click.option(
    "--profile", is_flag=True, help="Also time one loaded scene per material moved in place, and moment vs plain path."
)
@click.option(
    "--effects", is_flag=True, help="Run the effects benchmark instead: render time saved by each omitted effect."
)
@click.option(
    "--repeats",
    type=int,
    default=None,
    help=f"--effects: timed renders per variant, {span(REPEATS_RANGE)} [default: 5].",
)
@click.option(
    "--scale",
    default=None,
    metavar="N,N,...",
    help="Run the scale benchmark instead: build datasets of these sizes (renders, two or more, e.g. "
    "1000,10000,50000) from SPEC [default: manifests/paper.toml] at --resolution [16] and --spp [1], time "
    "every command over each and write README.md, scale.png and scale.json to --out (docs/results/scale/).",
)
@json_file_option("Also write the figures to this JSON file.")
@json_option("Print the figures as JSON on stdout (progress stays on stderr).")
@_friendly_errors
def bench_cmd(
    spec, limit, resolution, spp, workers, shard_size, out, profile, effects, repeats, scale, json_path, as_json
):
    """Build time over the summed time of bare Mitsuba renders of the same samples (docs/build.md).

    \b
    Example:
      shaderball bench manifests/smoke.toml --resolution 32 --spp 4 --workers 0
    """

    if scale is not None:
        if out is None:
            raise ShaderballError("--out: missing; --scale writes its results page to this folder")
        result = run_scale_bench(
            parse_int_list("--scale", scale, SCALE_SIZE_RANGE),
            out=out,
            spec_path=spec,
            resolution=resolution,
            spp=spp,
            json_path=json_path,
            progress=say,
        )
        _print_result(result, as_json)
        return
    result = run_from_args(
        spec,
        effects=effects,
        samples=limit,
        resolution=resolution,
        spp=spp,
        workers=workers,
        shard_size=shard_size,
        out=out,
        profile=profile,
        repeats=repeats,
        json_path=json_path,
        progress=say,
    )
    _print_result(result, as_json)


def _print_result(result, as_json: bool, **extra) -> None:
    """A command's summary: its lines, or with --json its fields (and ``extra``) as one document."""
    if as_json:
        _emit_json({**(result.to_dict() if hasattr(result, "to_dict") else dataclasses.asdict(result)), **extra})
        return
    for line in result.lines():
        click.echo(line)


@main.command("publish")
@click.argument("directory", metavar="DIR", type=click.Path())
@out_option(
    "New or empty folder for the publication: tar shards, samples.jsonl, README.md (dataset "
    "card), croissant.json, SHA256SUMS (docs/publish.md).",
    folder=True,
)
@click.option(
    "--shard-bytes",
    default=DEFAULT_SHARD_BYTES,
    show_default=True,
    type=int,
    help=f"Largest tar shard in bytes, {span(SHARD_BYTES_RANGE)}; shards hold whole materials "
    "(a larger material gets a shard of its own).",
)
@click.option(
    "--license",
    "license_id",
    default=DEFAULT_LICENSE,
    show_default=True,
    type=click.Choice(list(LICENSES)),
    help="License of the data, as the Hugging Face Hub names it (card and Croissant metadata).",
)
@click.option(
    "--url",
    default=None,
    help="Where the publication will live (Croissant's url), e.g. "
    "https://huggingface.co/datasets/ORG/NAME [default: none].",
)
@json_option("Print the summary (or the refusal) as JSON only.")
@_friendly_errors
def publish_cmd(directory, out, shard_bytes, license_id, url, as_json):
    """Publish a dataset that passes `shaderball validate` (checked first; exit 1 if not).

    Deterministic WebDataset-convention tar shards, a samples table, a dataset card with a
    contact sheet, Croissant metadata and SHA256SUMS; the same folder publishes to the same bytes.

    \b
    Example:
      shaderball publish demo-out/smoke --out demo-out/smoke-pub
    """
    summary = publish(
        directory,
        out,
        shard_bytes=shard_bytes,
        license_id=license_id,
        url=url,
        progress=say,
    )
    _print_result(summary, as_json)


@main.command("verify")
@click.argument("pub", metavar="PUB", type=click.Path())
@json_option("Print the report (or the refusal: kind, message) as JSON only.")
@_friendly_errors
def verify_cmd(pub, as_json):
    """Check a publication without extracting it: every file's SHA-256, every tar header and member.

    Exit 0 if intact, 1 if refused (the first problem is named), 2 for bad usage.

    \b
    Example:
      shaderball verify demo-out/smoke-pub
    """
    report = verify(pub, progress=say)
    _print_result(report, as_json)


@main.command("unpack")
@click.argument("pub", metavar="PUB", type=click.Path())
@out_option("New or empty folder for the dataset; left as it was if the publication is refused.", folder=True)
@click.option(
    "--no-validate",
    is_flag=True,
    help="Skip `shaderball validate` of the result (it needs the spec's svbrdf_folders, if any, on this machine).",
)
@json_option("Print the summary (or the refusal) as JSON only.")
@_friendly_errors
def unpack_cmd(pub, out, no_validate, as_json):
    """Restore the dataset folder of a publication, byte for byte, after verifying all of it.

    \b
    Example:
      shaderball unpack demo-out/smoke-pub --out demo-out/smoke-copy
    """
    summary = unpack(pub, out, validate_after=not no_validate, progress=say)
    _print_result(summary, as_json)


def _neural():
    """pipeline.neural imports torch: an optional dependency (the `train` extra), loaded only here."""
    try:
        import torch  # noqa: F401
    except ImportError:
        raise ShaderballError("the neural stage needs torch: pip install -e '.[train]'") from None


@main.command("train")
@click.argument("dataset", metavar="DATASET", type=click.Path())
@out_option(
    "Run folder (new, empty, or a run to resume): config.json, log.jsonl, loss.png, checkpoint.pt (weights and "
    "Adam's state, to resume; at 400 px 141 MB with --width 1, 37 MB with 0.5) and checkpoint-best.pt (weights "
    "only: 47 MB, 12 MB; scripts/checkpoint_sizes.py). [required, except with --benchmark]",
    folder=True,
    required=False,
)
@options_from(
    TrainConfig,
    *("epochs", "batch_size", "lr", "loss", "vgg_weights", "vgg_sha256", "vgg_weight", "device", "loader_workers"),
    *("seed", "resolution", "test_fraction", "split_seed", "train_materials", "width", "schedule", "warmup_epochs"),
    *("exposure", "check_hashes", "threads", "precision", "channels_last", "compile"),
    vgg_weights={"metavar": "FILE"},
    vgg_sha256={"metavar": "HEX"},
    check_hashes={"flag": "--hash-check/--no-hash-check"},
)
@renamed_option("--workers", "--loader-workers", "--workers means dask worker processes; train has none")
@click.option(
    "--benchmark",
    is_flag=True,
    help="Measure loader samples/s, training samples/s and inference ms instead of training; writes nothing.",
)
@json_option("Print the summary (or benchmark) as JSON on stdout.")
@_friendly_errors
def train_cmd(dataset, out, benchmark, as_json, **options):
    """Train the paper's network on a dataset folder or its publication (docs/neural.md); resumes a killed run.

    \b
    Example:
      shaderball train demo-out/smoke --out runs/smoke --epochs 1
    """
    _neural()
    from pipeline.neural.train import train

    if out is None and not benchmark:
        raise ShaderballError("--out: missing; name the run folder (or pass --benchmark)")
    config = TrainConfig(dataset=dataset, out=out or "", **options)
    if benchmark:
        from pipeline.neural.bench import benchmark as run_benchmark

        result = run_benchmark(config)
        lines, data = result.lines(), result.to_dict()
    else:
        summary = train(config, progress=None if as_json else training_progress())
        lines, data = summary.lines(), summary.to_dict()
    if as_json:
        _emit_json(data)
        return
    for line in lines:
        click.echo(line)


@main.command("infer")
@click.argument("run", metavar="RUN", type=click.Path())
@out_option(
    "Output EXR file: render.R/G/B, the network's estimate in linear HDR (inverse tone map), and the maps.",
    folder=False,
)
@click.option("--png", type=click.Path(dir_okay=False), default=None, help="Also write the network's picture as PNG.")
@material_options()
@light_options()
@device_option()
@json_option("Print the summary as JSON on stdout.")
@click.option(
    "--checkpoint",
    default="last",
    show_default=True,
    metavar="last|best|FILE",
    help="The last epoch's weights, the best held-out PSNR's (checkpoint-best.pt), or a checkpoint file of RUN.",
)
@_friendly_errors
def infer_cmd(run, out, png, device, as_json, checkpoint, **picture):
    """The trained network's picture of one material under one sun (no path tracing).

    \b
    Example:
      shaderball infer runs/smoke --out runs/smoke-ball.exr --png runs/smoke-ball.png --elevation 30 --roughness 0.2
    """
    _neural()
    from pipeline.neural.infer import InferRequest, infer_to_files

    request = InferRequest(run=run, out=out, png=png, device=device, checkpoint=checkpoint, **picture)
    summary = infer_to_files(request)
    if as_json:
        _emit_json(dict(summary.__dict__))
        return
    for line in summary.lines():
        click.echo(line)


@main.command("evaluate")
@click.argument("run", metavar="RUN", type=click.Path())
@click.argument("dataset", metavar="DATASET", type=click.Path())
@click.option(
    "--split",
    default="test",
    show_default=True,
    type=click.Choice(["test", "train", "all"]),
    help="The run's held-out (test) or training materials (DATASET must be the run's), or all samples.",
)
@out_option(
    "The one folder of the evaluation: results.json, results.md, grid.png (maps, reference, network, path "
    "tracing at equal time and 2 spp, denoised, error maps), and with --report the report "
    "[default: RUN/evaluation-SPLIT].",
    folder=True,
    required=False,
    dest="out_dir",
)
@json_file_option("Also write the results (per sample and mean) to this JSON file.")
@json_option("Print the summary as JSON on stdout (progress stays on stderr).")
@click.option(
    "--spp",
    default="1,2,4,16",
    show_default=True,
    metavar="N,N,...",
    help=f"Low-spp path tracing to compare with, each {span(SPP_LADDER_RANGE)}; 'none' for no path tracing.",
)
@click.option("--no-denoise", is_flag=True, help="Leave out the denoised (Intel OIDN) low-spp renders.")
@click.option("--limit", type=int, default=None, help="Evaluate at most this many samples [default: all].")
@device_option("auto: cuda when torch sees a GPU, else cpu.")
@click.option(
    "--checkpoint",
    default="last",
    show_default=True,
    metavar="last|best|FILE",
    help="The last epoch's weights; best: the best held-out PSNR's (chosen on the test split, so optimistic "
    "there); or a checkpoint file of RUN.",
)
@click.option(
    "--report",
    is_flag=True,
    help="Also write, into the --out folder: report.md (the table, per material class with 95% intervals, "
    "the grid), report.json, learning-curve.png/.csv (training and held-out loss and PSNR per epoch).",
)
@click.option(
    "--no-flip",
    is_flag=True,
    help="Leave out HDR-FLIP, the slowest metric (most of an evaluation's time at 64x64).",
)
@_friendly_errors
def evaluate_cmd(
    run, dataset, split, out_dir, json_path, spp, no_denoise, limit, device, checkpoint, report, no_flip, as_json
):
    """PSNR/SSIM (8-bit sRGB), relMSE and HDR-FLIP of the network against path-traced references.

    DATASET: a dataset folder or its publication. Low-spp renders are denoised with OIDN fed
    the first-hit albedo and normal, and on the colour alone (docs/neural.md).

    \b
    Example:
      shaderball evaluate runs/smoke demo-out/smoke --limit 2 --no-flip --report
    """
    _neural()
    from pipeline.neural.evaluate import EvaluateRequest, evaluate

    spp_list = parse_int_list("--spp", spp, SPP_LADDER_RANGE, none="none")
    request = EvaluateRequest(
        run=run,
        dataset=dataset,
        split=split,
        out_dir=out_dir,
        json_path=json_path,
        spp=spp_list,
        denoise=not no_denoise,
        limit=limit,
        device=device,
        checkpoint=checkpoint,
        report=report,
        flip=not no_flip,
    )
    _print_result(evaluate(request, progress=evaluate_progress()), as_json)


@main.command("serve")
@options_from(
    ServeOptions,
    *("run", "checkpoint", "dataset", "host", "port", "threads"),
    run={"metavar": "RUN"},
    checkpoint={"metavar": "last|best|FILE"},
    dataset={"metavar": "DIR|PUB"},
)
@click.option(
    "--benchmark",
    is_flag=True,
    help="Print the network's time per frame and the first path-traced pass's time instead of serving.",
)
@click.option("--repeats", default=9, show_default=True, type=int, help="--benchmark: slider moves timed, 1 to 100.")
@_friendly_errors
def serve_cmd(benchmark, repeats, **options):
    """A local web page: the network's picture beside progressive path tracing (docs/serve.md).

    \b
    Examples:
      shaderball serve --run runs/smoke --dataset demo-out/smoke --benchmark
      shaderball serve --run runs/smoke --dataset demo-out/smoke-pub
    """
    options = ServeOptions(**options)
    for line in serve_command(options, _live_network(options), benchmark, repeats, say=say).lines():
        click.echo(line)


def _live_network(options):
    """The loader of --run's network for `serve` (torch is imported only when there is one)."""
    if options.run is None:
        return None

    def load():
        _neural()
        from pipeline.neural.live import LiveNetwork

        return LiveNetwork(options.run, checkpoint=options.checkpoint, threads=options.threads)

    return load


# Commands over finished work: a network exported, runs compared, the docs' figures, the neural
# stage's benchmarks. The library functions they call return; the printing is here.

from pipeline.figures.albedo_table import markdown as albedo_markdown
from pipeline.figures.albedo_table import models_markdown
from pipeline.figures.contact_sheet import SHEET_SEED, write_contact_sheet
from pipeline.figures.sun_positions import sun_positions
from pipeline.neural.limits import TRAINING_VARIANTS
from pipeline.store.atomic import write_text_atomic

_CHECKPOINT_HELP = (
    "The last epoch's weights, the best held-out PSNR's (checkpoint-best.pt), or a checkpoint file of RUN."
)


@main.command("export")
@click.argument("run", metavar="RUN", type=click.Path())
@out_option("TorchScript file to write (.pt, .pth or .ts).", folder=False)
@click.option("--checkpoint", default="last", show_default=True, metavar="last|best|FILE", help=_CHECKPOINT_HELP)
@json_option("Print what the file's extra shaderball.json holds, and its path, as JSON on stdout.")
@_friendly_errors
def export_cmd(run, out, checkpoint, as_json):
    """The trained network as a TorchScript file, for torch without this package (docs/neural.md).

    \b
    Example:
      shaderball export runs/smoke --out runs/smoke/net.pt
    """
    _neural()
    from pipeline.neural.export import export_torchscript

    meta = export_torchscript(run, out, checkpoint)
    if as_json:
        _emit_json({"out": out, **meta})
        return
    click.echo(f"wrote {out}: TorchScript, {meta['resolution']}x{meta['resolution']}, {checkpoint} checkpoint")


@main.command("sweep")
@click.argument("reports", nargs=-1, required=True, metavar="REPORT.json...", type=click.Path(dir_okay=False))
@out_option("Folder for sweep.md, sweep.json and data-size.png.", folder=True)
@json_option("Print the summary (what sweep.json holds) as JSON on stdout instead of the table.")
@_friendly_errors
def sweep_cmd(reports, out, as_json):
    """Runs of several training-set sizes and seeds side by side: the data-size curve (docs/neural.md).

    Each REPORT.json is the report.json that `shaderball evaluate --report` wrote for a run;
    all must be evaluated on the same held-out samples of the same dataset.

    \b
    Example:
      shaderball sweep runs/smoke/evaluation-test/report.json --out runs/sweep
    """
    _neural()
    from pipeline.neural.sweep import write_sweep

    summary, text = write_sweep(list(reports), out)
    if as_json:
        _emit_json(summary)
        return
    click.echo(text, nl=False)


#: `shaderball figures NAME`: the options each figure takes (beyond --out and --json).
_FIGURE_OPTIONS = {
    "sun-positions": (),
    "contact-sheet": ("examples", "resolution", "seed"),
    "albedo-table": ("models", "no_samplers"),
}


@main.command("figures")
@click.argument("name", metavar="NAME", type=click.Choice(list(_FIGURE_OPTIONS)))
@out_option(
    "sun-positions, contact-sheet: the PNG file to write (required); albedo-table: a markdown file "
    "[default: print the tables].",
    folder=False,
    required=False,
)
@click.option("--examples", type=int, default=None, help="contact-sheet: materials per family, 1 to 64 [4].")
@click.option("--resolution", type=int, default=None, help="contact-sheet: map side in texels, 16 to 1024 [128].")
@click.option("--seed", type=int, default=None, help="contact-sheet: the sheet's seed [2019].")
@click.option("--models", is_flag=True, help="albedo-table: only the two material models side by side.")
@click.option("--no-samplers", is_flag=True, help="albedo-table: leave out the sampler statistics.")
@json_option("Print what was written (or the tables) as JSON on stdout.")
@_friendly_errors
def figures_cmd(name, out, examples, resolution, seed, models, no_samplers, as_json):
    """A figure or table of the docs, reproduced: sun-positions (README, about 20 s at its size),
    contact-sheet (docs/materials.md), albedo-table (docs/materials.md, about 10 s).

    \b
    Example:
      shaderball figures contact-sheet --out demo-out/sheet.png --examples 1 --resolution 16
    """
    given = {"examples": examples, "resolution": resolution, "seed": seed, "models": models, "no_samplers": no_samplers}
    for option, value in given.items():
        if value not in (None, False) and option not in _FIGURE_OPTIONS[name]:
            flag = "--" + option.replace("_", "-")
            raise ShaderballError(f"{flag}: not an option of {name}; it takes {_figure_options_text(name)}")
    if name != "albedo-table" and out is None:
        raise ShaderballError(f"--out: missing; {name} writes a PNG file (e.g. --out figures/{name}.png)")
    if name == "albedo-table":
        text = models_markdown() if models else albedo_markdown(with_samplers=not no_samplers, progress=say)
        if out is not None:
            write_text_atomic(out, text + "\n")
        if as_json:
            _emit_json({"figure": name, "out": out, "markdown": text})
        elif out is None:
            click.echo(text)
        else:
            click.echo(f"wrote {out}")
        return
    if name == "sun-positions":
        width, height = sun_positions(out, progress=say)
    else:
        width, height = write_contact_sheet(
            out,
            examples=4 if examples is None else examples,
            resolution=128 if resolution is None else resolution,
            seed=SHEET_SEED if seed is None else seed,
            progress=say,
        )
    if as_json:
        _emit_json({"figure": name, "out": out, "width": width, "height": height})
        return
    click.echo(f"wrote {out} ({width}x{height})")


def _figure_options_text(name: str) -> str:
    taken = ["--out", "--json", *("--" + o.replace("_", "-") for o in _FIGURE_OPTIONS[name])]
    return ", ".join(taken)


@main.group("neural-bench", cls=_Group)
def neural_bench():
    """The neural stage's measurements (docs/neural.md): KIND is loaders (a dataset folder
    against its publication), collate (torch's collation against ours, idle and loaded), denoise
    (what OIDN is fed) or train-options (training samples/s of each speed option).

    \b
    Example:
      shaderball neural-bench collate demo-out/smoke --repeats 1 --busy 0
    """


def _bench_output(result: dict, table: str, as_json: bool) -> None:
    if as_json:
        _emit_json(result)
        return
    click.echo(table, nl=False)


@neural_bench.command("loaders")
@click.argument("folder", metavar="DIR", type=click.Path())
@click.argument("pub", metavar="PUB", type=click.Path())
@click.option("--resolution", type=int, default=None, help="Network resolution in pixels [default: the dataset's].")
@click.option("--batch-size", type=int, default=6, show_default=True, help="Samples per batch.")
@click.option("--loader-workers", type=int, default=0, show_default=True, help="DataLoader worker processes.")
@click.option("--repeats", type=int, default=3, show_default=True, help="Passes over each; the best counts.")
@click.option("--no-hash-check", is_flag=True, help="Skip each file's SHA-256 check.")
@json_option("Print every figure as JSON on stdout instead of the table.")
@_friendly_errors
def neural_bench_loaders_cmd(folder, pub, resolution, batch_size, loader_workers, repeats, no_hash_check, as_json):
    """The loader's samples/s on a dataset folder DIR and on its publication PUB, passes alternated.

    \b
    Example:
      shaderball neural-bench loaders demo-out/smoke demo-out/smoke-pub --repeats 1
    """
    _neural()
    from pipeline.neural.bench import compare_loaders, loaders_table

    result = compare_loaders(
        folder, pub, resolution, batch_size, loader_workers, repeats, not no_hash_check, progress=say
    )
    _bench_output(result, loaders_table(result), as_json)


@neural_bench.command("collate")
@click.argument("dataset", metavar="DATASET", type=click.Path())
@click.option(
    "--busy", type=int, default=2, show_default=True, help="Spinning processes of the loaded passes, 0 to 64."
)
@click.option("--repeats", type=int, default=5, show_default=True, help="Rounds of passes; medians count.")
@click.option("--batch-size", type=int, default=6, show_default=True, help="Samples per batch.")
@click.option("--loader-workers", type=int, default=0, show_default=True, help="DataLoader worker processes.")
@click.option("--resolution", type=int, default=None, help="Network resolution in pixels [default: the dataset's].")
@json_option("Print every figure as JSON on stdout instead of the table.")
@_friendly_errors
def neural_bench_collate_cmd(dataset, busy, repeats, batch_size, loader_workers, resolution, as_json):
    """The loader's samples/s with torch's default collation and with the project's, on the
    machine as it is and with --busy spinning processes beside it.

    \b
    Example:
      shaderball neural-bench collate demo-out/smoke --repeats 1 --busy 0
    """
    _neural()
    from pipeline.neural.bench import collation_table, compare_collation

    result = compare_collation(dataset, busy, repeats, batch_size, loader_workers, resolution, progress=say)
    _bench_output(result, collation_table(result), as_json)


@neural_bench.command("denoise")
@click.argument("dataset", metavar="DATASET", type=click.Path())
@click.option("--limit", type=int, default=12, show_default=True, help="Samples compared, spread over the dataset.")
@click.option("--spp", default="1,4,16", show_default=True, metavar="N,N,...", help="Path-tracing rates denoised.")
@click.option("--reference-spp", type=int, default=256, show_default=True, help="Samples per pixel of the reference.")
@json_option("Print every figure as JSON on stdout instead of the table.")
@_friendly_errors
def neural_bench_denoise_cmd(dataset, limit, spp, reference_spp, as_json):
    """OIDN fed each choice of auxiliary buffers, against fresh high-spp renders of the same
    samples (the dataset must store texture maps).

    \b
    Example:
      shaderball neural-bench denoise demo-out/smoke --limit 1 --spp 1 --reference-spp 4
    """
    _neural()
    from pipeline.neural.bench import compare_denoisers, denoise_table

    result = compare_denoisers(dataset, limit, parse_int_list("--spp", spp, SPP_RANGE), reference_spp, progress=say)
    _bench_output(result, denoise_table(result), as_json)


@neural_bench.command("train-options")
@click.option("--resolution", type=int, default=64, show_default=True, help="Network resolution in pixels.")
@options_from(TrainConfig, "batch_size", "loss", **{"loss": {"default": "l1+vgg"}})
@click.option("--repeats", type=int, default=5, show_default=True, help="Rounds of timed steps; medians count.")
@click.option("--steps", type=int, default=3, show_default=True, help="Steps timed per variant and round.")
@options_from(TrainConfig, "threads")
@click.option(
    "--variants",
    default=None,
    metavar="NAME,NAME,...",
    help="Speed options compared, comma-separated, the first the baseline: "
    + "; ".join(TRAINING_VARIANTS)
    + " [default: all].",
)
@json_option("Print every figure as JSON on stdout instead of the table.")
@_friendly_errors
def neural_bench_train_options_cmd(resolution, batch_size, loss, repeats, steps, threads, variants, as_json):
    """Training samples/s of each speed option (random inputs, a fresh network each), variants
    alternated; a randomly initialised VGG16 stands in for ImageNet weights.

    \b
    Example:
      shaderball neural-bench train-options --resolution 32 --loss l1 --repeats 1 --steps 1 --variants baseline,--channels-last
    """
    _neural()
    from pipeline.neural.bench import compare_training, training_table
    from pipeline.neural.train import TrainConfig

    config = TrainConfig(
        dataset="",
        out="",
        batch_size=batch_size,
        loss=loss,
        device="cpu",
        threads=threads,
        precision="fp32",
        channels_last=False,
    )
    names = None if variants is None else [name.strip() for name in variants.split(",")]
    result = compare_training(config, resolution, names, repeats, steps, progress=say)
    _bench_output(result, training_table(result), as_json)


if __name__ == "__main__":
    signal.signal(signal.SIGINT, signal.default_int_handler)
    main()
