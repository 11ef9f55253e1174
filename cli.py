"""shaderball's command line: a thin click face over the library.

Each command parses its options, calls one library function, prints a short
summary and maps the project's own error (:class:`pipeline.errors.ShaderballError`)
to a message on stderr and exit code 2. Logic lives in the packages.
"""

from __future__ import annotations

import functools
import sys

import click

from materials.brdf_ref import DEFAULT_MODEL, MODELS
from pipeline.bench.build_bench import run_from_args
from pipeline.check.info import dataset_info
from pipeline.check.preview import write_preview
from pipeline.check.validate import repair, validate
from pipeline.errors import USER_ERRORS, ShaderballError, caused_by_interrupt, filesystem_error
from pipeline.publish.facts import LICENSES
from pipeline.publish.refusal import Refused
from pipeline.publish.unpack import unpack
from pipeline.publish.verify import verify
from pipeline.publish.writer import DEFAULT_LICENSE, DEFAULT_SHARD_BYTES, SHARD_BYTES_RANGE, publish
from pipeline.render.command import RenderRequest, parse_triple, render_to_files
from pipeline.render.limits import MAX_DEPTH_RANGE, RESOLUTION_RANGE, SPP_RANGE, span
from pipeline.render.mitsuba_env import VARIANT_CHOICES
from pipeline.render.scene_command import write_scene
from pipeline.run.build import build
from pipeline.run.cluster import ClusterOptions, job_script
from pipeline.study.run import StudyRequest, parse_families, parse_ladder, run_study
from sky.emitter import DEFAULT_SUN, SUN_MODES

#: Exit code of a command stopped by Ctrl-C (SIGINT): 128 + 2, as shells report it.
INTERRUPTED_EXIT = 130


def _interrupted():
    click.echo(
        "\ninterrupted (Ctrl-C): every write is atomic, nothing is torn; run the same command again to resume",
        err=True,
    )
    sys.exit(INTERRUPTED_EXIT)


def _friendly_errors(func):
    """Turn a user error (pipeline.errors.USER_ERRORS) into `error: ...` on stderr and its exit
    code; an OSError the library did not name (a file system refusing a write) into one line
    and exit code 4; Ctrl-C into one line saying how to go on, exit code 130. No traceback."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except USER_ERRORS as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(exc.exit_code)
        except OSError as exc:
            error = filesystem_error(exc, "?", "fix the cause and run the same command again")
            click.echo(f"error: {error}", err=True)
            sys.exit(error.exit_code)
        except KeyboardInterrupt:
            _interrupted()
        except RuntimeError as exc:  # Ctrl-C inside a callback of Mitsuba's, wrapped by drjit
            if not caused_by_interrupt(exc):
                raise
            _interrupted()

    return wrapper


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(package_name="shaderball")
def main():
    """Build, validate and train from datasets of path-traced material renders on a shaderball.

    Every sample pairs four screen-space material maps (diffuse, specular, roughness,
    normal) and a lighting vector (sun direction, turbidity) with a Mitsuba 3 path-traced
    render of the shaderball under a Hosek-Wilkie sun and sky.
    """


@main.command("scene")
@click.option(
    "--out",
    "out_dir",
    required=True,
    type=click.Path(file_okay=False),
    help="Output folder; created if missing. Receives shaderball.ply, gbuffer.exr, preview.png.",
)
@click.option(
    "--resolution",
    default=400,
    show_default=True,
    type=int,
    help=f"Image width and height in pixels, {span(RESOLUTION_RANGE)}.",
)
@click.option(
    "--variant",
    default="auto",
    show_default=True,
    type=click.Choice(VARIANT_CHOICES),
    help="Mitsuba backend: auto picks cuda when a GPU works, else llvm (the CPU).",
)
@_friendly_errors
def scene_cmd(out_dir: str, resolution: int, variant: str):
    """Write the shaderball mesh, its G-buffer and a preview picture."""

    summary = write_scene(out_dir, resolution=resolution, variant=variant)
    for line in summary.lines():
        click.echo(line)


@main.command("render")
@click.option(
    "--diffuse",
    default="0.5,0.5,0.5",
    show_default=True,
    metavar="R,G,B",
    help="Uniform diffuse albedo, linear RGB, each in [0, 1].",
)
@click.option(
    "--specular",
    default="0.04,0.04,0.04",
    show_default=True,
    metavar="R,G,B",
    help="Uniform specular albedo (F0), linear RGB, each in [0, 1]. 0.04 is a typical dielectric.",
)
@click.option(
    "--roughness",
    default=0.3,
    show_default=True,
    type=float,
    help="Uniform roughness in [0, 1]; GGX alpha = roughness^2.",
)
@click.option(
    "--normal",
    default="0,0,1",
    show_default=True,
    metavar="X,Y,Z",
    help="Uniform tangent-space normal (Z > 0; normalised).",
)
@click.option(
    "--svbrdf",
    type=click.Path(),
    default=None,
    help="Spatially varying material instead of the uniform values: a Deschaintre et al. "
    "PNG strip (photo|normal|diffuse|roughness|specular) or a folder of maps.",
)
@click.option(
    "--svbrdf-colorspace",
    type=click.Choice(["raw", "srgb"]),
    default="raw",
    show_default=True,
    help="How 8-bit albedo maps of --svbrdf are decoded: raw (as Deschaintre's renderer) or sRGB.",
)
@click.option(
    "--elevation",
    default=45.0,
    show_default=True,
    type=float,
    help="Sun elevation above the horizon, degrees in [0, 90]. Below ~2.4-7 degrees "
    "(by turbidity) the sun is raised to the floor where Mitsuba's sky is non-negative; "
    "the move is printed and recorded.",
)
@click.option(
    "--azimuth",
    default=270.0,
    show_default=True,
    type=float,
    help="Sun azimuth, degrees in [-360, 720], counter-clockwise from +x seen from above: "
    "0 lights the ball from the image's right, 90 from behind, 270 from the camera's side.",
)
@click.option(
    "--turbidity",
    default=3.0,
    show_default=True,
    type=float,
    help="Atmospheric turbidity in [1, 10] (1: very clear, 10: hazy).",
)
@click.option(
    "--spp", default=150, show_default=True, type=int, help=f"Samples per pixel, {span(SPP_RANGE)} (the paper: 150)."
)
@click.option(
    "--resolution",
    default=400,
    show_default=True,
    type=int,
    help=f"Image width and height in pixels, {span(RESOLUTION_RANGE)}.",
)
@click.option(
    "--max-depth", default=8, show_default=True, type=int, help=f"Path length limit, {span(MAX_DEPTH_RANGE)}."
)
@click.option("--seed", default=0, show_default=True, type=int, help="Render seed, 0 to 2^32-1.")
@click.option(
    "--variant",
    default="auto",
    show_default=True,
    type=click.Choice(VARIANT_CHOICES),
    help="Mitsuba backend: auto picks cuda when a GPU works, else llvm (the CPU).",
)
@click.option(
    "--sun",
    type=click.Choice(SUN_MODES),
    default=DEFAULT_SUN,
    show_default=True,
    help="split: delta sun + sky-only sunsky (measured default, docs/sky.md); sunsky: the sun disk inside sunsky.",
)
@click.option(
    "--model",
    type=click.Choice(MODELS),
    default=DEFAULT_MODEL,
    show_default=True,
    help="Material model: shaderball (GGX as published, energy-conserving) or deschaintre2018 "
    "(Deschaintre et al.'s code, with its floors on GGX D and Smith G1; darker below "
    "roughness 0.178; docs/materials.md). A spec's materials.model.",
)
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(dir_okay=False),
    help="Output EXR: layers render.R/G/B (float32) and the screen-space maps.",
)
@click.option("--png", type=click.Path(dir_okay=False), default=None, help="Also write a tone-mapped PNG for people.")
@_friendly_errors
def render_cmd(
    diffuse,
    specular,
    roughness,
    normal,
    svbrdf,
    svbrdf_colorspace,
    elevation,
    azimuth,
    turbidity,
    spp,
    resolution,
    max_depth,
    seed,
    variant,
    sun,
    model,
    out,
    png,
):
    """Render one material on the shaderball under one sun and sky."""

    request = RenderRequest(
        diffuse=parse_triple("--diffuse", diffuse),
        specular=parse_triple("--specular", specular),
        roughness=roughness,
        normal=parse_triple("--normal", normal, None, None),
        svbrdf=svbrdf,
        svbrdf_colorspace=svbrdf_colorspace,
        elevation_deg=elevation,
        azimuth_deg=azimuth,
        turbidity=turbidity,
        spp=spp,
        resolution=resolution,
        max_depth=max_depth,
        seed=seed,
        sun=sun,
        variant=variant,
        model=model,
        out=out,
        png=png,
    )
    for line in render_to_files(request).lines():
        click.echo(line)


def _format_seconds(seconds: float | None) -> str:
    if seconds is None:
        return "--:--"
    seconds = int(seconds)
    return (
        f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"
        if seconds >= 3600
        else f"{seconds // 60}:{seconds % 60:02d}"
    )


def _progress_printer():
    """A one-line progress bar on stderr: count, percentage, renders/s, elapsed, ETA, and what the
    build waits on (workers, batch jobs pending and why), printed again when either changes."""
    interactive = sys.stderr.isatty()
    last = {"done": -1, "message": "", "width": 0}

    def show(p):
        message = getattr(p, "message", "")
        if p.done == last["done"] and message == last["message"]:
            return
        last["done"], last["message"] = p.done, message
        width = 30
        filled = int(width * p.done / p.total) if p.total else width
        line = (
            f"[{'#' * filled}{'.' * (width - filled)}] {p.done}/{p.total} renders "
            f"{100.0 * p.done / max(p.total, 1):5.1f}%  {p.rate:.2f}/s  "
            f"elapsed {_format_seconds(p.elapsed_s)}  ETA {_format_seconds(p.eta_s)}"
            + (f"  | {message}" if message else "")
        )
        padded, last["width"] = line.ljust(last["width"]), len(line)
        click.echo(("\r" + padded) if interactive else line, err=True, nl=not interactive)
        if interactive and p.done >= p.total:
            click.echo("", err=True)

    return show


@main.command("build")
@click.argument("spec", type=click.Path(dir_okay=False))
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(file_okay=False),
    help="Dataset directory. Created if missing; an existing one built from the same spec is "
    "resumed (only missing or unverified samples are rendered); another spec is refused.",
)
@click.option(
    "--workers",
    type=int,
    default=None,
    help="Local dask worker processes, 0 to 1024 [default: one per 2 cores]. 0 runs in this "
    "process without dask. Ignored with --scheduler.",
)
@click.option(
    "--scheduler",
    default=None,
    metavar="ADDRESS",
    help="Use an existing dask scheduler, e.g. tcp://10.0.0.1:8786, instead of a local cluster "
    "(its workers need DIR at the same path; docs/cluster.md).",
)
@click.option(
    "--allow-spec-change",
    is_flag=True,
    help="Accept a spec that differs from DIR/spec.toml in dataset.name or dataset.version only "
    "(no sample depends on them); any other difference is refused.",
)
@click.option(
    "--cluster",
    "cluster_kind",
    type=click.Choice(["local", "slurm", "pbs"]),
    default="local",
    show_default=True,
    help="Where workers run: this machine, or batch jobs via dask-jobqueue.",
)
@click.option("--jobs", type=int, default=None, help="slurm/pbs: batch jobs (nodes), 1 to 10000; one worker each.")
@click.option("--cores", type=int, default=None, help="slurm/pbs: cores per job, 1 to 1024; every render uses all.")
@click.option(
    "--memory",
    default=None,
    metavar="SIZE",
    help="Memory per worker (local) or per job (slurm/pbs), e.g. 16GiB; a worker past 95% of "
    "its limit is restarted and its shard runs again.",
)
@click.option(
    "--walltime",
    default=None,
    metavar="HH:MM:SS",
    help="slurm/pbs: wall-clock limit per job, 00:01:00 to 9999:59:59; workers retire about 5 min "
    "(or 5%; half the walltime below 10 min) before it and a new job replaces each.",
)
@click.option("--queue", default=None, help="slurm/pbs: partition or queue.")
@click.option("--account", default=None, help="slurm/pbs: account to charge.")
@click.option(
    "--scratch",
    default=None,
    metavar="DIR",
    help="slurm/pbs: node-local folder for the kernel cache and dask's files "
    "[default: ${TMPDIR:-/tmp}, expanded on the node].",
)
@click.option(
    "--recycle-after",
    type=int,
    default=2000,
    show_default=True,
    metavar="RENDERS",
    help="Restart a dask worker process once it has rendered this many samples, 0 to 10000000 "
    "(bounds Mitsuba's slow memory growth, docs/cluster.md); 0: never.",
)
@click.option(
    "--start-timeout",
    type=int,
    default=None,
    metavar="SECONDS",
    help="Stop (exit 2, naming the jobs and why they wait) when the build has had no worker for "
    "this long, 10 to 10000000: before the first one arrives, or after the last one left "
    "(e.g. a partition down). The dataset resumes with the same command. [default: wait "
    "as long as it takes]",
)
@click.option(
    "--print-job-script",
    is_flag=True,
    help="slurm/pbs: print the batch script each job would run, then exit; nothing is submitted or written.",
)
@_friendly_errors
def build_cmd(
    spec,
    out,
    workers,
    scheduler,
    allow_spec_change,
    cluster_kind,
    jobs,
    cores,
    memory,
    walltime,
    queue,
    account,
    scratch,
    recycle_after,
    start_timeout,
    print_job_script,
):
    """Build (or resume) a dataset of renders from a spec (see manifests/ and docs/spec.md).

    Clusters, SLURM/PBS and worker memory: docs/cluster.md. Resume and crash safety: docs/resume.md.
    """

    options = ClusterOptions(
        kind=cluster_kind,
        workers=workers,
        scheduler=scheduler,
        jobs=jobs,
        cores=cores,
        memory=memory,
        walltime=walltime,
        queue=queue,
        account=account,
        scratch=scratch,
        recycle_after=recycle_after,
        start_timeout=start_timeout,
    ).check()
    if print_job_script:
        if not options.is_jobqueue:
            raise click.UsageError("--print-job-script needs --cluster slurm or --cluster pbs")
        click.echo(job_script(options), nl=False)
        return

    def started(where, dashboard):
        click.echo(f"building with {where}" + (f"; dashboard {dashboard}" if dashboard else ""), err=True)

    summary = build(
        spec, out, cluster=options, allow_spec_change=allow_spec_change, progress=_progress_printer(), on_start=started
    )
    for line in summary.lines():
        click.echo(line)


@main.command("validate")
@click.argument("directory", metavar="DIR", type=click.Path())
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="Print the report as JSON on stdout: expected/present/valid render counts and "
    "problems [{kind, id, path, message}] (docs/validate.md).",
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
@click.option(
    "--workers",
    type=int,
    default=0,
    show_default=True,
    help="With --repair: local dask worker processes for re-rendering; 0 renders in this process.",
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
    """
    import json
    import time

    if fast and fix:
        raise click.UsageError("--fast and --repair cannot be combined: a repair needs the full check")
    if spec_path and not fix:
        raise click.UsageError("--spec is used only with --repair")
    last = {"t": 0.0}

    def show(p):
        now = time.monotonic()
        if p.done < p.total and now - last["t"] < 1.0:
            return
        last["t"] = now
        read = f"files, {p.bytes_read / 1e6:.1f} MB read" if p.stage == "check" else "renders done"
        click.echo(f"{p.stage}: {p.done}/{p.total} {read}, {_format_seconds(p.elapsed_s)}", err=True)

    if fix:
        before, report, actions = repair(directory, workers=workers, progress=show, spec_path=spec_path)
    else:
        before, report, actions = None, validate(directory, fast=fast, progress=show), []
    if as_json:
        out = report.to_dict()
        if fix:
            out["repair"] = {"before": before.to_dict(), "actions": [a.to_dict() for a in actions]}
        click.echo(json.dumps(out, indent=2))
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
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(dir_okay=False),
    help="PNG to write: one row per sample, its tone-mapped render beside its four maps, "
    "labelled with its id, material and lighting.",
)
@click.option(
    "--samples",
    default=8,
    show_default=True,
    type=int,
    help="Rows, 1 to 200: samples spread evenly over the renders recorded so far.",
)
@click.option(
    "--tile",
    default=None,
    type=int,
    help="Picture size in pixels, 32 to 1024 [default: the render size, scaled to 128-256].",
)
@_friendly_errors
def preview_cmd(directory, out, samples, tile):
    """A contact sheet of a dataset (complete or partial) for people to look at."""

    for line in write_preview(directory, out, samples=samples, tile=tile).lines():
        click.echo(line)


@main.command("info")
@click.argument("directory", metavar="DIR", type=click.Path())
@click.option("--json", "as_json", is_flag=True, help="Print the figures as JSON instead.")
@_friendly_errors
def info_cmd(directory, as_json):
    """Counts, sizes, spec summary and completion of a dataset folder (works on partial builds)."""

    info = dataset_info(directory)
    if as_json:
        import json

        click.echo(json.dumps(info.to_dict(), sort_keys=True, indent=1))
        return
    for line in info.lines():
        click.echo(line)


@main.command("study")
@click.argument("spec", type=click.Path(dir_okay=False))
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(file_okay=False),
    help="Study folder: request.json, references/, rows/, then study.json, study.csv, pareto.png, "
    "report.md. Re-running the same command resumes; another request is refused.",
)
@click.option(
    "--samples",
    type=int,
    default=12,
    show_default=True,
    help="Samples drawn from the spec's plan, spread over material classes, sun, turbidity and roughness; 1 to 1000.",
)
@click.option(
    "--reference-spp",
    type=int,
    default=4096,
    show_default=True,
    help="Samples per pixel of each reference (two halves); even, at least twice the largest spp "
    "studied, at most 65536.",
)
@click.option(
    "--resolution",
    type=int,
    default=None,
    help=f"Render size in pixels, {span(RESOLUTION_RANGE)} [default: the spec's].",
)
@click.option(
    "--ladder",
    default="1,2,4,8,16,32,64,128,150,256,512,1024",
    show_default=True,
    help="spp ladder of the independent sampler, comma-separated, 1 to 16384 (the spec's spp is always added).",
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
@click.option(
    "--repeats",
    type=int,
    default=3,
    show_default=True,
    help="Independent seeds per sample and configuration, 1 to 64 (the cost grows in proportion); "
    "every figure carries a 95% interval over samples and seeds.",
)
@click.option("--no-flip", is_flag=True, help="Leave HDR-FLIP out (the slowest metric).")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON on stdout (progress stays on stderr).")
@_friendly_errors
def study_cmd(spec, out, samples, reference_spp, resolution, ladder, families, only, repeats, no_flip, as_json):
    """What accuracy costs in time: error-vs-time of render recipes against references (docs/accuracy.md)."""

    def progress(p):
        click.echo(f"[{p['done']}/{p['total']}] {p['what']}  elapsed {_format_seconds(p['elapsed_s'])}", err=True)

    req = StudyRequest(
        spec=spec,
        out=out,
        samples=samples,
        reference_spp=reference_spp,
        resolution=resolution,
        ladder=parse_ladder(ladder),
        families=parse_families(families),
        only=tuple(n for n in only.split(",") if n),
        flip=not no_flip,
        repeats=repeats,
    )
    summary = run_study(req, progress=progress)
    if as_json:
        import json

        click.echo(json.dumps(summary.to_dict(), sort_keys=True, indent=1))
        return
    for line in summary.lines():
        click.echo(line)


@main.command("bench")
@click.argument("spec", required=False, type=click.Path(dir_okay=False))
@click.option(
    "--samples",
    type=int,
    default=None,
    help="Cut the spec to about this many renders (whole materials, all their lightings) [default: all of them].",
)
@click.option(
    "--resolution",
    type=int,
    default=None,
    help=f"Render size in pixels, {span(RESOLUTION_RANGE)} [default: the spec's; with --effects 128].",
)
@click.option(
    "--spp",
    type=int,
    default=None,
    help=f"Samples per pixel, {span(SPP_RANGE)} [default: the spec's; with --effects 64].",
)
@click.option(
    "--workers",
    type=int,
    default=None,
    help="As `shaderball build --workers` (0: in this process) [default: the build's].",
)
@click.option(
    "--shard-size",
    type=int,
    default=None,
    help="Materials per shard, 1 to 1000000 [default: the spec's]; with few materials use 1 so "
    "every worker gets a shard.",
)
@click.option(
    "--out",
    "out",
    type=click.Path(file_okay=False),
    default=None,
    help="Keep the benchmark's dataset in this new or empty folder [default: a temporary one].",
)
@click.option(
    "--profile", is_flag=True, help="Also time one loaded scene per material moved in place, and moment vs plain path."
)
@click.option(
    "--effects", is_flag=True, help="Run the effects benchmark instead: render time saved by each omitted effect."
)
@click.option("--repeats", type=int, default=None, help="--effects: timed renders per variant, 1 to 100 [default: 5].")
@click.option(
    "--json",
    "json_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Also write the figures to this JSON file.",
)
@_friendly_errors
def bench_cmd(spec, samples, resolution, spp, workers, shard_size, out, profile, effects, repeats, json_path):
    """Build time over the summed time of bare Mitsuba renders of the same samples (docs/build.md)."""

    result = run_from_args(
        spec,
        effects=effects,
        samples=samples,
        resolution=resolution,
        spp=spp,
        workers=workers,
        shard_size=shard_size,
        out=out,
        profile=profile,
        repeats=repeats,
        json_path=json_path,
        progress=lambda message: click.echo(message, err=True),
    )
    for line in result.lines():
        click.echo(line)


def _refusals_as_json(as_json: bool):
    """With --json, a refused dataset or publication is printed as JSON on stdout (exit 1)."""
    import contextlib
    import json

    @contextlib.contextmanager
    def guard():
        try:
            yield
        except Refused as exc:
            if not as_json:
                raise
            click.echo(json.dumps({"ok": False, **exc.to_dict()}, indent=1, sort_keys=True))
            sys.exit(exc.exit_code)

    return guard()


def _print_result(result, as_json: bool) -> None:
    if as_json:
        import json

        click.echo(json.dumps(result.to_dict(), indent=1, sort_keys=True))
        return
    for line in result.lines():
        click.echo(line)


@main.command("publish")
@click.argument("directory", metavar="DIR", type=click.Path())
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(file_okay=False),
    help="New or empty folder for the publication: tar shards, samples.jsonl, README.md (dataset "
    "card), croissant.json, SHA256SUMS (docs/publish.md).",
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
@click.option("--json", "as_json", is_flag=True, help="Print the summary (or the refusal) as JSON only.")
@_friendly_errors
def publish_cmd(directory, out, shard_bytes, license_id, url, as_json):
    """Publish a dataset that passes `shaderball validate` (checked first; exit 1 if not).

    Deterministic WebDataset-convention tar shards, a samples table, a dataset card with a
    contact sheet, Croissant metadata and SHA256SUMS; the same folder publishes to the same bytes.
    """
    with _refusals_as_json(as_json):
        summary = publish(
            directory,
            out,
            shard_bytes=shard_bytes,
            license_id=license_id,
            url=url,
            progress=lambda message: click.echo(message, err=True),
        )
    _print_result(summary, as_json)


@main.command("verify")
@click.argument("pub", metavar="PUB", type=click.Path())
@click.option("--json", "as_json", is_flag=True, help="Print the report (or the refusal: kind, message) as JSON only.")
@_friendly_errors
def verify_cmd(pub, as_json):
    """Check a publication without extracting it: every file's SHA-256, every tar header and member.

    Exit 0 if intact, 1 if refused (the first problem is named), 2 for bad usage.
    """
    with _refusals_as_json(as_json):
        report = verify(pub, progress=lambda message: click.echo(message, err=True))
    _print_result(report, as_json)


@main.command("unpack")
@click.argument("pub", metavar="PUB", type=click.Path())
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(file_okay=False),
    help="New or empty folder for the dataset; left as it was if the publication is refused.",
)
@click.option(
    "--no-validate",
    is_flag=True,
    help="Skip `shaderball validate` of the result (it needs the spec's svbrdf_folders, if any, on this machine).",
)
@click.option("--json", "as_json", is_flag=True, help="Print the summary (or the refusal) as JSON only.")
@_friendly_errors
def unpack_cmd(pub, out, no_validate, as_json):
    """Restore the dataset folder of a publication, byte for byte, after verifying all of it."""
    with _refusals_as_json(as_json):
        summary = unpack(
            pub, out, validate_after=not no_validate, progress=lambda message: click.echo(message, err=True)
        )
    _print_result(summary, as_json)


def _neural():
    """pipeline.neural imports torch: an optional dependency (the `train` extra), loaded only here."""
    try:
        import torch  # noqa: F401
    except ImportError:
        raise ShaderballError("the neural stage needs torch: pip install -e '.[train]'") from None


def _training_progress():
    """One line on stderr per batch: epoch, batch, loss, samples/s, ETA."""
    interactive = sys.stderr.isatty()

    def show(p):
        width = 20
        filled = int(width * p["batch"] / p["batches"])
        line = (
            f"epoch {p['epoch']}/{p['epochs']} [{'#' * filled}{'.' * (width - filled)}] "
            f"batch {p['batch']}/{p['batches']}  loss {p['loss']:.4f}  {p['samples_per_s']:.1f} samples/s  "
            f"ETA {_format_seconds(p['eta_s'])}"
        )
        click.echo(("\r" + line) if interactive else line, err=True, nl=not interactive)
        if interactive and p["batch"] == p["batches"]:
            click.echo("", err=True)

    return show


@main.command("train")
@click.argument("dataset", metavar="DATASET", type=click.Path())
@click.option(
    "--out",
    "out",
    type=click.Path(file_okay=False),
    default=None,
    help="Run folder (new, empty, or a run to resume): config.json, log.jsonl, checkpoint.pt, loss.png.",
)
@click.option(
    "--epochs",
    default=30,
    show_default=True,
    type=int,
    help="Epochs to reach, 1 to 100000; running again with more continues the run.",
)
@click.option(
    "--batch-size", default=6, show_default=True, type=int, help="Samples per step, 1 to 4096 (the paper: 6)."
)
@click.option(
    "--lr", default=1e-2, show_default=True, type=float, help="Adam learning rate in (0, 10] (the paper: 1e-2)."
)
@click.option(
    "--loss",
    default="l1+vgg",
    show_default=True,
    type=click.Choice(["l1+vgg", "l1"]),
    help="l1+vgg: L1 + VGG16 relu3_3 feature loss (the paper's; needs VGG16 weights); l1: L1 alone.",
)
@click.option(
    "--vgg-weights",
    type=click.Path(dir_okay=False),
    default=None,
    help="torchvision's vgg16 state dict (vgg16-397923af.pth) [default: torch hub's cache, "
    "$TORCH_HOME/hub/checkpoints/]. Never downloaded.",
)
@click.option(
    "--vgg-sha256",
    default=None,
    metavar="HEX",
    help="Expected SHA-256 of --vgg-weights [default: torchvision's ImageNet file's].",
)
@click.option(
    "--vgg-weight", default=1.0, show_default=True, type=float, help="Weight of the VGG term beside L1, >= 0."
)
@click.option(
    "--device",
    default="auto",
    show_default=True,
    type=click.Choice(["auto", "cpu", "cuda"]),
    help="auto: cuda when torch sees a GPU, else cpu.",
)
@click.option("--workers", default=0, show_default=True, type=int, help="DataLoader worker processes, 0 to 64.")
@click.option("--seed", default=0, show_default=True, type=int, help="Seeds weights, order and split, 0 to 2^63-1.")
@click.option(
    "--resolution",
    default=None,
    type=int,
    help="Network resolution, a multiple of 16 dividing the dataset's (images box-averaged) [default: the dataset's].",
)
@click.option(
    "--test-fraction",
    default=0.2,
    show_default=True,
    type=float,
    help="Fraction of materials held out for testing, in [0, 1).",
)
@click.option("--no-hash-check", is_flag=True, help="Skip each file's SHA-256 check on first read.")
@click.option(
    "--benchmark",
    is_flag=True,
    help="Measure loader samples/s, training samples/s and inference ms instead of training; writes nothing.",
)
@click.option("--json", "as_json", is_flag=True, help="Print the summary (or benchmark) as JSON on stdout.")
@_friendly_errors
def train_cmd(
    dataset,
    out,
    epochs,
    batch_size,
    lr,
    loss,
    vgg_weights,
    vgg_sha256,
    vgg_weight,
    device,
    workers,
    seed,
    resolution,
    test_fraction,
    no_hash_check,
    benchmark,
    as_json,
):
    """Train the paper's network on a dataset folder or its publication (docs/neural.md); resumes a killed run."""
    _neural()
    from pipeline.neural.train import TrainConfig, train

    if out is None and not benchmark:
        raise ShaderballError("--out: missing; name the run folder (or pass --benchmark)")
    config = TrainConfig(
        dataset=dataset,
        out=out or "",
        epochs=epochs,
        batch_size=batch_size,
        lr=lr,
        loss=loss,
        vgg_weights=vgg_weights,
        vgg_sha256=vgg_sha256,
        vgg_weight=vgg_weight,
        device=device,
        workers=workers,
        seed=seed,
        resolution=resolution,
        test_fraction=test_fraction,
        check_hashes=not no_hash_check,
    )
    if benchmark:
        from pipeline.neural.bench import benchmark as run_benchmark

        result = run_benchmark(config)
        lines, data = result.lines(), result.to_dict()
    else:
        summary = train(config, progress=None if as_json else _training_progress())
        lines, data = summary.lines(), summary.to_dict()
    if as_json:
        import json

        click.echo(json.dumps(data, sort_keys=True, indent=1))
        return
    for line in lines:
        click.echo(line)


@main.command("infer")
@click.argument("run", metavar="RUN", type=click.Path())
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(dir_okay=False),
    help="Output EXR: render.R/G/B, the network's estimate in linear HDR (inverse tone map), and the maps.",
)
@click.option("--png", type=click.Path(dir_okay=False), default=None, help="Also write the network's picture as PNG.")
@click.option(
    "--diffuse",
    default="0.5,0.5,0.5",
    show_default=True,
    metavar="R,G,B",
    help="Uniform diffuse albedo, linear RGB, each in [0, 1].",
)
@click.option(
    "--specular",
    default="0.04,0.04,0.04",
    show_default=True,
    metavar="R,G,B",
    help="Uniform specular albedo (F0), linear RGB, each in [0, 1].",
)
@click.option("--roughness", default=0.3, show_default=True, type=float, help="Uniform roughness in [0, 1].")
@click.option(
    "--normal",
    default="0,0,1",
    show_default=True,
    metavar="X,Y,Z",
    help="Uniform tangent-space normal (Z > 0; normalised).",
)
@click.option(
    "--svbrdf", type=click.Path(), default=None, help="Spatially varying material, as `shaderball render --svbrdf`."
)
@click.option(
    "--svbrdf-colorspace",
    type=click.Choice(["raw", "srgb"]),
    default="raw",
    show_default=True,
    help="How 8-bit albedo maps of --svbrdf are decoded.",
)
@click.option(
    "--elevation",
    default=45.0,
    show_default=True,
    type=float,
    help="Sun elevation, degrees in [0, 90] (raised to the low-sun floor as `shaderball render` does).",
)
@click.option("--azimuth", default=270.0, show_default=True, type=float, help="Sun azimuth, degrees in [-360, 720].")
@click.option("--turbidity", default=3.0, show_default=True, type=float, help="Atmospheric turbidity in [1, 10].")
@click.option("--device", default="auto", show_default=True, type=click.Choice(["auto", "cpu", "cuda"]))
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON on stdout.")
@_friendly_errors
def infer_cmd(
    run,
    out,
    png,
    diffuse,
    specular,
    roughness,
    normal,
    svbrdf,
    svbrdf_colorspace,
    elevation,
    azimuth,
    turbidity,
    device,
    as_json,
):
    """The trained network's picture of one material under one sun (no path tracing)."""
    _neural()
    from pipeline.neural.infer import InferRequest, infer_to_files

    request = InferRequest(
        run=run,
        out=out,
        png=png,
        diffuse=parse_triple("--diffuse", diffuse),
        specular=parse_triple("--specular", specular),
        roughness=roughness,
        normal=parse_triple("--normal", normal, None, None),
        svbrdf=svbrdf,
        svbrdf_colorspace=svbrdf_colorspace,
        elevation_deg=elevation,
        azimuth_deg=azimuth,
        turbidity=turbidity,
        device=device,
    )
    summary = infer_to_files(request)
    if as_json:
        import json

        click.echo(json.dumps(summary.__dict__, sort_keys=True, indent=1))
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
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False),
    default=None,
    help="Folder for results.json, results.md and grid.png [default: RUN/evaluation-SPLIT].",
)
@click.option(
    "--json",
    "json_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Also write the results (per sample and mean) to this JSON file.",
)
@click.option(
    "--spp",
    default="1,2,4,16",
    show_default=True,
    metavar="N,N,...",
    help="Low-spp path tracing to compare with, each 1 to 4096; 'none' for no path tracing.",
)
@click.option("--no-denoise", is_flag=True, help="Leave out the denoised (Intel OIDN) low-spp renders.")
@click.option("--limit", type=int, default=None, help="Evaluate at most this many samples [default: all].")
@click.option("--device", default="auto", show_default=True, type=click.Choice(["auto", "cpu", "cuda"]))
@_friendly_errors
def evaluate_cmd(run, dataset, split, out_dir, json_path, spp, no_denoise, limit, device):
    """PSNR/SSIM (8-bit sRGB), relMSE and HDR-FLIP of the network against path-traced references.

    DATASET: a dataset folder or its publication. Low-spp renders are denoised with OIDN fed
    the first-hit albedo and normal, and on the colour alone (docs/neural.md).
    """
    _neural()
    from pipeline.neural.evaluate import EvaluateRequest, evaluate

    if spp.strip().lower() == "none":
        spp_list = ()
    else:
        try:
            spp_list = tuple(int(x) for x in spp.split(","))
        except ValueError:
            raise ShaderballError(
                f"--spp: {spp!r} is not allowed; allowed: comma-separated integers from 1 to 4096, or none"
            ) from None
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
    )
    summary = evaluate(
        request, progress=lambda p: click.echo(f"sample {p['sample']}/{p['samples']} {p['id']}", err=True)
    )
    for line in summary.lines():
        click.echo(line)


if __name__ == "__main__":
    main()
