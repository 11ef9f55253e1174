"""shaderball's command line: a thin click face over the library.

Each command is generated from one checked request of the library
(:func:`pipeline.ui.command.request_command`: its options, operands, defaults, ranges and
help come from the request's declared fields); its body calls one library function with the
request and returns the result, which is printed (or, with --json, one JSON document). How a
command ends (messages, exit codes, Ctrl-C) is :mod:`pipeline.ui.process`'s. Logic lives in
the packages.
"""

# ruff: noqa: E402 - the imports come after the Ctrl-C handler that covers them

from __future__ import annotations

from pipeline.ui.interrupt import stop_on_ctrl_c_while_loading

# However cli.py is started (the `shaderball` script imports it; `python -m cli` runs it), until
# a command's body starts: Python's own handler is back then (pipeline.ui.process).
stop_on_ctrl_c_while_loading()

import dataclasses

import click

from pipeline.bench.command import BenchRequest, run_bench
from pipeline.bench.estimate import PlanRequest, plan_spec
from pipeline.bench.info import info
from pipeline.check.preview import write_preview
from pipeline.check.request import InfoRequest, PreviewRequest, ValidateRequest
from pipeline.downstream.command import study_command
from pipeline.downstream.request import StudyCommandRequest
from pipeline.neural.command import (
    bench_command,
    evaluate_command,
    export_command,
    infer_command,
    live_network,
    stored_renders,
    sweep_command,
    train_command,
)
from pipeline.neural.config import (
    CollateRequest,
    DenoiseRequest,
    EvaluateRequest,
    ExportRequest,
    InferRequest,
    LoadersRequest,
    SweepRequest,
    TrainConfig,
    TrainOptionsRequest,
)
from pipeline.publish.request import PublishRequest, UnpackRequest, VerifyRequest
from pipeline.publish.unpack import unpack
from pipeline.publish.verify import verify
from pipeline.publish.writer import publish
from pipeline.render.command import RenderRequest, render_to_files
from pipeline.render.scene_command import SceneRequest, write_scene
from pipeline.run.command import build_command
from pipeline.run.repair import validate_or_repair
from pipeline.run.request import BuildRequest
from pipeline.serve.command import ServeOptions, serve_command
from pipeline.ui import process
from pipeline.ui.command import Group, command_line, renamed_option, request_command
from pipeline.ui.progress import (
    build_progress,
    evaluate_progress,
    render_progress,
    say,
    study_progress,
    training_progress,
    validate_progress,
)

INTERNAL_EXIT = process.INTERNAL_EXIT


@click.group(cls=Group, context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
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


@request_command(
    main, SceneRequest, json="Print what was written (files, mesh and atlas figures, times) as JSON on stdout."
)
def scene_cmd(request: SceneRequest):
    """Write the shaderball mesh, its G-buffer and a preview picture.

    \b
    Example:
      shaderball scene --out demo-out/scene --resolution 64
    """
    return write_scene(request)


@request_command(
    main,
    RenderRequest,
    json="Print what was written (files, render statistics and time, lighting, effects) as JSON on stdout.",
)
def render_cmd(request: RenderRequest):
    """Render one material on the shaderball under one sun and sky.

    \b
    Example:
      shaderball render --out demo-out/ball.exr --png demo-out/ball.png --resolution 64 --spp 16 --elevation 30
    """
    return render_to_files(request, progress=render_progress())


@request_command(
    main,
    BuildRequest,
    json="Print what was built (folder, manifest, counts, seconds) as JSON on stdout; progress stays on stderr.",
)
def build_cmd(request: BuildRequest):
    """Build (or resume) a dataset of renders from a spec (see manifests/ and docs/spec.md).

    Clusters, SLURM/PBS and worker memory: docs/cluster.md. Resume and crash safety: docs/resume.md.

    \b
    Example:
      shaderball build manifests/smoke.toml --out demo-out/smoke
    """
    return build_command(request, progress=build_progress(), say=say)


@request_command(
    main,
    ValidateRequest,
    json="Print the report as JSON on stdout: expected/present/valid render counts and "
    "problems [{kind, id, path, message}] (docs/validate.md).",
)
def validate_cmd(request: ValidateRequest):
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
    return validate_or_repair(request, progress=validate_progress())


@request_command(
    main,
    PreviewRequest,
    renamed=(renamed_option("--limit", "--rows"), renamed_option("--samples", "--rows")),
    json="Print what was written (the picture, its samples, what was left out) as JSON on stdout.",
)
def preview_cmd(request: PreviewRequest):
    """A contact sheet of a dataset (complete or partial) for people to look at.

    \b
    Example:
      shaderball preview demo-out/smoke --out demo-out/smoke-preview.png
    """
    return write_preview(request)


@request_command(main, InfoRequest, json="Print the figures as JSON instead.")
def info_cmd(request: InfoRequest):
    """Counts, sizes, spec summary and completion of a dataset folder (works on partial builds).

    Given a spec file instead: what `shaderball plan SPEC` prints without timing (counts, shards, disk).

    \b
    Examples:
      shaderball info demo-out/smoke
      shaderball info manifests/paper.toml
    """
    return info(request)


@request_command(
    main,
    PlanRequest,
    renamed=(renamed_option("--limit", "--renders"), renamed_option("--samples", "--renders")),
    json="Print the plan as JSON on stdout.",
)
def plan_cmd(request: PlanRequest):
    """What building SPEC takes, before building it: renders, materials, lightings, shards, disk, time.

    The time comes from the spec's own first renders, built here at the spec's settings
    (seconds to minutes; nothing is kept), extrapolated per worker (docs/build.md).

    \b
    Examples:
      shaderball plan manifests/smoke.toml
      shaderball plan manifests/smoke.toml --cluster slurm --jobs 8 --cores 32
    """
    return plan_spec(request, progress=say)


@request_command(
    main,
    StudyCommandRequest,
    renamed=(renamed_option("--samples", "--draws"),),
    skip=("scan",),
    json="Print the summary as JSON on stdout (progress stays on stderr).",
    needs_torch=lambda request: request.downstream,
)
def study_cmd(request: StudyCommandRequest):
    """What accuracy costs in time: error-vs-time of render recipes against references, or with
    --downstream of the network trained on builds at each spp (docs/accuracy.md).

    \b
    Examples:
      shaderball study manifests/smoke.toml --out demo-out/smoke-study --resolution 16 \\
        --configs ladder --ladder 4 --reference-spp 64 --repeats 1 --no-flip
      shaderball study manifests/smoke.toml --downstream --out demo-out/smoke-downstream \\
        --ladder 4,16 --repeats 2 --epochs 1 --resolution 32 --reference-spp 256
    """
    return study_command(
        request, progress=study_progress, command=command_line("study", request, every=True, skip=request.unused())
    )


@request_command(
    main,
    BenchRequest,
    renamed=(renamed_option("--limit", "--renders"), renamed_option("--samples", "--renders")),
    json="Print the figures as JSON on stdout (progress stays on stderr).",
)
def bench_cmd(request: BenchRequest):
    """Build time over the summed time of bare Mitsuba renders of the same samples (docs/build.md).

    \b
    Example:
      shaderball bench manifests/smoke.toml --resolution 32 --spp 4 --workers 0
    """
    return run_bench(request, progress=say)


@request_command(main, PublishRequest, json="Print the summary (or the refusal) as JSON only.")
def publish_cmd(request: PublishRequest):
    """Publish a dataset that passes `shaderball validate` (checked first; exit 1 if not).

    Deterministic WebDataset-convention tar shards, a samples table, a dataset card with a
    contact sheet, Croissant metadata and SHA256SUMS; the same folder publishes to the same bytes.

    \b
    Example:
      shaderball publish demo-out/smoke --out demo-out/smoke-pub
    """
    return publish(request, progress=say)


@request_command(main, VerifyRequest, json="Print the report (or the refusal: kind, message) as JSON only.")
def verify_cmd(request: VerifyRequest):
    """Check a publication without extracting it: every file's SHA-256, every tar header and member.

    Exit 0 if intact, 1 if refused (the first problem is named), 2 for bad usage.

    \b
    Example:
      shaderball verify demo-out/smoke-pub
    """
    return verify(request, progress=say)


@request_command(main, UnpackRequest, json="Print the summary (or the refusal) as JSON only.")
def unpack_cmd(request: UnpackRequest):
    """Restore the dataset folder of a publication, byte for byte, after verifying all of it.

    \b
    Example:
      shaderball unpack demo-out/smoke-pub --out demo-out/smoke-copy
    """
    return unpack(request, progress=say)


@request_command(
    main,
    TrainConfig,
    renamed=(renamed_option("--workers", "--loader-workers", "--workers means dask worker processes; train has none"),),
    json="Print the summary (or benchmark) as JSON on stdout.",
    needs_torch=True,
)
def train_cmd(request: TrainConfig, as_json: bool):
    """Train the paper's network on a dataset folder or its publication (docs/neural.md); resumes a killed run.

    \b
    Example:
      shaderball train demo-out/smoke --out runs/smoke --epochs 1
    """
    return train_command(request, progress=None if as_json else training_progress())


@request_command(main, InferRequest, json="Print the summary as JSON on stdout.", needs_torch=True)
def infer_cmd(request: InferRequest):
    """The trained network's picture of one material under one sun (no path tracing).

    \b
    Example:
      shaderball infer runs/smoke --out runs/smoke-ball.exr --png runs/smoke-ball.png --elevation 30 --roughness 0.2
    """
    return infer_command(request)


@request_command(
    main,
    EvaluateRequest,
    renamed=(renamed_option("--samples", "--limit"),),
    json="Print the summary as JSON on stdout (progress stays on stderr).",
    needs_torch=True,
)
def evaluate_cmd(request: EvaluateRequest):
    """PSNR/SSIM (8-bit sRGB), relMSE and HDR-FLIP of the network against path-traced references.

    DATASET: a dataset folder or its publication. Low-spp renders are denoised with OIDN fed
    the first-hit albedo and normal, and on the colour alone (docs/neural.md).

    \b
    Example:
      shaderball evaluate runs/smoke demo-out/smoke --limit 2 --no-flip --report
    """
    return evaluate_command(
        request,
        progress=evaluate_progress(),
        command=command_line("evaluate", dataclasses.replace(request, out=request.folder)),
    )


@request_command(
    main,
    ServeOptions,
    json="Print the summary (with --benchmark: its figures) as JSON on stdout.",
    needs_torch=lambda request: request.run is not None,
)
def serve_cmd(request: ServeOptions):
    """A local web page: the network's picture beside progressive path tracing (docs/serve.md).

    \b
    Examples:
      shaderball serve --run runs/smoke --dataset demo-out/smoke --benchmark
      shaderball serve --run runs/smoke --dataset demo-out/smoke-pub
    """
    return serve_command(request, say=say, network=live_network, stored=stored_renders)


# Commands over finished work: a network exported, runs compared, the docs' figures, the neural
# stage's benchmarks. The library functions they call return; the printing is here.

from pipeline.figures.command import FiguresRequest, make_figure


@request_command(
    main,
    ExportRequest,
    json="Print what the file's extra shaderball.json holds, and its path, as JSON on stdout.",
    needs_torch=True,
)
def export_cmd(request: ExportRequest):
    """The trained network as a TorchScript file, for torch without this package (docs/neural.md).

    \b
    Example:
      shaderball export runs/smoke --out runs/smoke/net.pt
    """
    return export_command(request)


@request_command(
    main,
    SweepRequest,
    json="Print the summary (what sweep.json holds) as JSON on stdout instead of the table.",
    needs_torch=True,
)
def sweep_cmd(request: SweepRequest):
    """Runs of several training-set sizes and seeds side by side: the data-size curve (docs/neural.md).

    Each REPORT.json is the report.json that `shaderball evaluate --report` wrote for a run;
    all must be evaluated on the same held-out samples of the same dataset.

    \b
    Example:
      shaderball sweep runs/smoke/evaluation-test/report.json --out runs/sweep
    """
    return sweep_command(request, command=command_line("sweep", request))


@request_command(main, FiguresRequest, json="Print what was written (or the tables) as JSON on stdout.")
def figures_cmd(request: FiguresRequest):
    """A figure or table of the docs, reproduced: sun-positions (README, about 20 s at its size),
    contact-sheet (docs/materials.md), albedo-table (docs/materials.md, about 10 s), scenes (README:
    one material on the four built-in objects under the shipped environment maps, about 10 s).

    \b
    Example:
      shaderball figures contact-sheet --out demo-out/sheet.png --examples 1 --resolution 16
    """
    return make_figure(request, progress=say)


@main.group("neural-bench", cls=Group, subcommand_metavar="KIND [ARGS]...")
def neural_bench():
    """The neural stage's measurements (docs/neural.md): KIND is loaders (a dataset folder
    against its publication), collate (torch's collation against ours, idle and loaded), denoise
    (what OIDN is fed) or train-options (training samples/s of each speed option).

    \b
    Example:
      shaderball neural-bench collate demo-out/smoke --repeats 1 --busy 0
    """


_BENCH_JSON = "Print every figure as JSON on stdout instead of the table."


@request_command(neural_bench, LoadersRequest, name="loaders", json=_BENCH_JSON, needs_torch=True)
def neural_bench_loaders_cmd(request: LoadersRequest):
    """The loader's samples/s on a dataset folder DIR and on its publication PUB, passes alternated.

    \b
    Example:
      shaderball neural-bench loaders demo-out/smoke demo-out/smoke-pub --repeats 1
    """
    return bench_command(request, progress=say)


@request_command(neural_bench, CollateRequest, name="collate", json=_BENCH_JSON, needs_torch=True)
def neural_bench_collate_cmd(request: CollateRequest):
    """The loader's samples/s with torch's default collation and with the project's, on the
    machine as it is and with --busy spinning processes beside it.

    \b
    Example:
      shaderball neural-bench collate demo-out/smoke --repeats 1 --busy 0
    """
    return bench_command(request, progress=say)


@request_command(
    neural_bench,
    DenoiseRequest,
    name="denoise",
    renamed=(
        renamed_option("--limit", "--draws", "samples drawn spread over the dataset"),
        renamed_option("--samples", "--draws"),
    ),
    json=_BENCH_JSON,
    needs_torch=True,
)
def neural_bench_denoise_cmd(request: DenoiseRequest):
    """OIDN fed each choice of auxiliary buffers, against fresh high-spp renders of the same
    samples (the dataset must store texture maps).

    \b
    Example:
      shaderball neural-bench denoise demo-out/smoke --draws 1 --spp 1 --reference-spp 4
    """
    return bench_command(request, progress=say)


@request_command(neural_bench, TrainOptionsRequest, name="train-options", json=_BENCH_JSON, needs_torch=True)
def neural_bench_train_options_cmd(request: TrainOptionsRequest):
    """Training samples/s of each speed option (random inputs, a fresh network each), variants
    alternated; a randomly initialised VGG16 stands in for ImageNet weights.

    \b
    Example:
      shaderball neural-bench train-options --resolution 32 --loss l1 --repeats 1 --steps 1 --variants baseline,--channels-last
    """
    return bench_command(request, progress=say)


if __name__ == "__main__":
    main()
