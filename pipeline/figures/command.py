"""`shaderball figures NAME`: one request (:class:`FiguresRequest`), a figure or table of
the docs made again.

``sun-positions`` (the README's figure, :mod:`pipeline.figures.sun_positions`),
``contact-sheet`` (docs/materials.md, :mod:`pipeline.figures.contact_sheet`),
``albedo-table`` (docs/materials.md, :mod:`pipeline.figures.albedo_table`) and ``scenes`` (the
README's objects under the shipped environment maps, :mod:`pipeline.figures.scenes`). Each figure
takes its own fields; another figure's is refused, naming it.
"""

from __future__ import annotations

from dataclasses import dataclass

from pipeline.fields import Checked, declared, default_of, field
from pipeline.fields.rules import Bool, Choice, Int, Optional, Path
from pipeline.figures.albedo_table import markdown, models_markdown
from pipeline.figures.contact_sheet import EXAMPLES_RANGE, RESOLUTION_RANGE, SHEET_SEED, write_contact_sheet
from pipeline.figures.scenes import DEFAULT_SPP, DEFAULT_TILE, SPP_RANGE, TILE_RANGE, write_scenes
from pipeline.figures.sun_positions import sun_positions
from pipeline.store.atomic import write_text_atomic

#: Each figure and the fields it takes beside its name and ``out``.
FIGURES = {
    "sun-positions": (),
    "contact-sheet": ("examples", "resolution", "seed"),
    "albedo-table": ("models", "no_samplers"),
    "scenes": ("tile", "spp"),
}
#: Figures written as PNG files (``out`` required); the others print their text without one.
PNG_FIGURES = ("sun-positions", "contact-sheet", "scenes")


@dataclass(frozen=True)
class FiguresRequest(Checked):
    """What `shaderball figures` is asked."""

    name: str = field(rule=Choice(tuple(FIGURES)), doc="The figure.", positional=True, metavar="NAME")
    out: str | None = field(
        None,
        rule=Optional(Path("a file"), "unset (print the tables)"),
        doc="sun-positions, contact-sheet, scenes: the PNG file to write (they need one); albedo-table: a "
        "markdown file [default: print the tables].",
        metavar="FILE",
    )
    examples: int = field(4, rule=Int(*EXAMPLES_RANGE), doc="contact-sheet: materials per family.", unit="materials")
    resolution: int = field(
        128, rule=Int(*RESOLUTION_RANGE), doc="contact-sheet: map side of each material.", unit="texels"
    )
    seed: int = field(SHEET_SEED, rule=Int(0, 2**63 - 1), doc="contact-sheet: the sheet's seed.")
    models: bool = field(False, rule=Bool(), doc="albedo-table: only the two material models side by side.")
    no_samplers: bool = field(False, rule=Bool(), doc="albedo-table: leave out the sampler statistics.")
    tile: int = field(DEFAULT_TILE, rule=Int(*TILE_RANGE), doc="scenes: width and height of each tile.", unit="pixels")
    spp: int = field(DEFAULT_SPP, rule=Int(*SPP_RANGE), doc="scenes: samples per pixel of each tile.", unit="samples")

    def check_cross(self) -> None:
        takes = FIGURES[self.name]
        for name in (n for options in FIGURES.values() for n in options):
            if name not in takes and getattr(self, name) != default_of(declared(type(self))[name]):
                raise self.field_error(
                    name,
                    getattr(self, name),
                    f"{self.name} takes " + ", ".join("{%s}" % n for n in ("out", *takes)),
                    what=f"not an option of {self.name}",
                )
        if self.name in PNG_FIGURES and self.out is None:
            raise self.field_error(
                "out", None, f"a PNG file for {self.name}, e.g. {{out}} figures/{self.name}.png", what="missing"
            )


@dataclass
class Figure:
    """What was written (a PNG's size), or the tables (``markdown``)."""

    figure: str
    out: str | None
    width: int | None = None
    height: int | None = None
    markdown: str | None = None

    def to_dict(self) -> dict:
        if self.markdown is not None:
            return {"figure": self.figure, "out": self.out, "markdown": self.markdown}
        return {"figure": self.figure, "out": self.out, "width": self.width, "height": self.height}

    def lines(self) -> list[str]:
        if self.markdown is None:
            return [f"wrote {self.out} ({self.width}x{self.height})"]
        return [f"wrote {self.out}"] if self.out is not None else self.markdown.split("\n")


def make_figure(request: FiguresRequest, progress=None) -> Figure:
    """Make the figure ``request`` names (``progress(str)`` hears of its steps)."""
    if request.name == "albedo-table":
        text = (
            models_markdown() if request.models else markdown(with_samplers=not request.no_samplers, progress=progress)
        )
        if request.out is not None:
            write_text_atomic(request.out, text + "\n")
        return Figure(request.name, request.out, markdown=text)
    if request.name == "sun-positions":
        width, height = sun_positions(request.out, progress=progress)
    elif request.name == "scenes":
        width, height = write_scenes(request.out, tile=request.tile, spp=request.spp, progress=progress)
    else:
        width, height = write_contact_sheet(
            request.out,
            examples=request.examples,
            resolution=request.resolution,
            seed=request.seed,
            progress=progress,
        )
    return Figure(request.name, request.out, width, height)
