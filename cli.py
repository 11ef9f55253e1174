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


if __name__ == "__main__":
    main()
