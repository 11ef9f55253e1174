"""shaderball's command line: a thin click face over the library.

Each command parses its options, calls one library function, prints a short
summary and maps the project's own error (:class:`pipeline.errors.ShaderballError`)
to a message on stderr and exit code 2. Logic lives in the packages.
"""

from __future__ import annotations

import functools
import sys

import click

from pipeline.errors import ShaderballError


def _friendly_errors(func):
    """Turn a ShaderballError into `error: ...` on stderr and its exit code."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except ShaderballError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(exc.exit_code)

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
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Output folder; created if missing. Receives shaderball.ply, gbuffer.exr, preview.png.")
@click.option("--resolution", default=400, show_default=True, type=int,
              help="Image width and height in pixels, 16 to 4096.")
@_friendly_errors
def scene_cmd(out_dir: str, resolution: int):
    """Write the shaderball mesh, its G-buffer and a preview picture."""
    from pipeline.scene_cmd import write_scene

    summary = write_scene(out_dir, resolution=resolution)
    for line in summary.lines():
        click.echo(line)


@main.command("render")
@click.option("--diffuse", default="0.5,0.5,0.5", show_default=True, metavar="R,G,B",
              help="Uniform diffuse albedo, linear RGB, each in [0, 1].")
@click.option("--specular", default="0.04,0.04,0.04", show_default=True, metavar="R,G,B",
              help="Uniform specular albedo (F0), linear RGB, each in [0, 1]. 0.04 is a typical dielectric.")
@click.option("--roughness", default=0.3, show_default=True, type=float,
              help="Uniform roughness in [0, 1]; GGX alpha = roughness^2.")
@click.option("--normal", default="0,0,1", show_default=True, metavar="X,Y,Z",
              help="Uniform tangent-space normal (Z > 0; normalised).")
@click.option("--svbrdf", type=click.Path(), default=None,
              help="Spatially varying material instead of the uniform values: a Deschaintre et al. "
                   "PNG strip (photo|normal|diffuse|roughness|specular) or a folder of maps.")
@click.option("--svbrdf-colorspace", type=click.Choice(["raw", "srgb"]), default="raw", show_default=True,
              help="How 8-bit albedo maps of --svbrdf are decoded: raw (as Deschaintre's renderer) or sRGB.")
@click.option("--elevation", default=45.0, show_default=True, type=float,
              help="Sun elevation above the horizon, degrees in [0, 90]. Below ~2.4-7 degrees "
                   "(by turbidity) the sun is raised to the floor where Mitsuba's sky is non-negative; "
                   "the move is printed and recorded.")
@click.option("--azimuth", default=270.0, show_default=True, type=float,
              help="Sun azimuth, degrees in [-360, 720], counter-clockwise from +x seen from above: "
                   "0 lights the ball from the image's right, 90 from behind, 270 from the camera's side.")
@click.option("--turbidity", default=3.0, show_default=True, type=float,
              help="Atmospheric turbidity in [1, 10] (1: very clear, 10: hazy).")
@click.option("--spp", default=150, show_default=True, type=int, help="Samples per pixel, 1 to 65536 (the paper: 150).")
@click.option("--resolution", default=400, show_default=True, type=int, help="Image width and height in pixels, 16 to 4096.")
@click.option("--max-depth", default=8, show_default=True, type=int, help="Path length limit, 1 to 64.")
@click.option("--seed", default=0, show_default=True, type=int, help="Render seed, 0 to 2^32-1.")
@click.option("--sun", type=click.Choice(["split", "sunsky"]), default="split", show_default=True,
              help="split: delta sun + sky-only sunsky (measured default, docs/sky.md); sunsky: the sun disk inside sunsky.")
@click.option("--out", "out", required=True, type=click.Path(dir_okay=False),
              help="Output EXR: layers render.R/G/B (float32) and the screen-space maps.")
@click.option("--png", type=click.Path(dir_okay=False), default=None, help="Also write a tone-mapped PNG for people.")
@_friendly_errors
def render_cmd(diffuse, specular, roughness, normal, svbrdf, svbrdf_colorspace, elevation, azimuth,
               turbidity, spp, resolution, max_depth, seed, sun, out, png):
    """Render one material on the shaderball under one sun and sky."""
    from pipeline.render_cmd import RenderRequest, parse_triple, render_to_files

    request = RenderRequest(
        diffuse=parse_triple("--diffuse", diffuse), specular=parse_triple("--specular", specular),
        roughness=roughness, normal=parse_triple("--normal", normal, None, None), svbrdf=svbrdf,
        svbrdf_colorspace=svbrdf_colorspace, elevation_deg=elevation, azimuth_deg=azimuth,
        turbidity=turbidity, spp=spp, resolution=resolution, max_depth=max_depth, seed=seed, sun=sun,
        out=out, png=png,
    )
    for line in render_to_files(request).lines():
        click.echo(line)


def _format_seconds(seconds: float | None) -> str:
    if seconds is None:
        return "--:--"
    seconds = int(seconds)
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}" if seconds >= 3600 else f"{seconds // 60}:{seconds % 60:02d}"


def _progress_printer():
    """A one-line progress bar on stderr: count, percentage, renders/s, elapsed, ETA."""
    interactive = sys.stderr.isatty()
    last = {"done": -1}

    def show(p):
        if p.done == last["done"] and p.done < p.total:
            return
        last["done"] = p.done
        width = 30
        filled = int(width * p.done / p.total) if p.total else width
        line = (f"[{'#' * filled}{'.' * (width - filled)}] {p.done}/{p.total} renders "
                f"{100.0 * p.done / max(p.total, 1):5.1f}%  {p.rate:.2f}/s  "
                f"elapsed {_format_seconds(p.elapsed_s)}  ETA {_format_seconds(p.eta_s)}")
        click.echo(("\r" + line) if interactive else line, err=True, nl=not interactive)
        if interactive and p.done >= p.total:
            click.echo("", err=True)

    return show


@main.command("build")
@click.argument("spec", type=click.Path(dir_okay=False))
@click.option("--out", "out", required=True, type=click.Path(file_okay=False),
              help="Dataset directory. Created if missing; an existing one built from the same spec is "
                   "resumed (only missing or unverified samples are rendered); another spec is refused.")
@click.option("--workers", type=int, default=None,
              help="Local dask worker processes, 0 to 1024 [default: one per 2 cores]. 0 runs in this "
                   "process without dask. Ignored with --scheduler.")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Use an existing dask scheduler, e.g. tcp://10.0.0.1:8786, instead of a local cluster.")
@_friendly_errors
def build_cmd(spec, out, workers, scheduler):
    """Build (or resume) a dataset of renders from a spec (see manifests/ and docs/spec.md)."""
    from pipeline.build import build

    def started(where, dashboard):
        click.echo(f"building with {where}" + (f"; dashboard {dashboard}" if dashboard else ""), err=True)

    summary = build(spec, out, workers=workers, scheduler=scheduler, progress=_progress_printer(),
                    on_start=started)
    for line in summary.lines():
        click.echo(line)


if __name__ == "__main__":
    main()
