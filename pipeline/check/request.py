"""What `shaderball validate`, `preview` and `info` are asked: one checked request each
(pipeline.fields); the command line is generated from them.

A dataset folder that cannot be read as one is a refusal of the request's ``directory``
field (:func:`dir_refused`), however a surface spells it (``DIR`` on the command line).
"""

from __future__ import annotations

from dataclasses import dataclass

from pipeline.dataset.spec_file import SPEC_FILE
from pipeline.fields import Checked, field
from pipeline.fields.rules import Bool, Int, Optional, Path, Text, format_value

#: preview's rows: samples spread over the renders recorded so far.
ROWS_RANGE = (1, 200)
#: preview's picture size in pixels.
TILE_RANGE = (32, 1024)
#: validate --repair's local dask workers (0: in this process).
REPAIR_WORKERS_RANGE = (0, 1024)

DATASET_FOLDER = "a dataset folder written by `shaderball build`"


def dataset_operand(doc: str = "The dataset folder.", metavar: str = "DIR", what: str = DATASET_FOLDER, exists="any"):
    """The dataset folder operand (``DIR``) of validate, preview, info, publish and
    neural-bench loaders, declared once."""
    return field(rule=Path(what, exists=exists), doc=doc, positional=True, metavar=metavar)


@dataclass(frozen=True)
class ValidateRequest(Checked):
    """`shaderball validate`: a dataset folder checked, and with ``repair`` mended."""

    directory: str = dataset_operand()
    repair: bool = field(
        False,
        rule=Bool(),
        doc="Fix what is bad (delete extra files, regenerate or re-render bad files and records, "
        "rewrite the manifest), then validate again. Renders are deterministic: repaired "
        "files are byte-identical to the originals.",
    )
    fast: bool = field(
        False, rule=Bool(), doc="Check sizes, markers and records only; read no file (no SHA-256, no decoding)."
    )
    workers: int = field(
        0,
        rule=Int(*REPAIR_WORKERS_RANGE),
        doc="With {repair}: local dask worker processes for re-rendering; 0 renders in this process.",
        unit="processes",
    )
    spec: str | None = field(
        None,
        rule=Optional(SPEC_FILE, "unset (DIR/spec.toml)"),
        doc="With {repair}: restore an unreadable or edited DIR/spec.toml from this spec, "
        "if its digest is the one dataset.json records.",
        metavar="SPEC",
    )

    def check_cross(self) -> None:
        if self.fast and self.repair:
            raise self.field_error("fast", True, "a repair needs the full check", what="not allowed with {repair}")
        if self.spec is not None and not self.repair:
            raise self.field_error("spec", self.spec, "give {repair} too", what="used only with {repair}")
        if self.workers and not self.repair:
            raise self.field_error("workers", self.workers, "give {repair} too", what="used only with {repair}")


@dataclass(frozen=True)
class PreviewRequest(Checked):
    """`shaderball preview`: a contact sheet of a dataset, complete or partial."""

    directory: str = dataset_operand()
    out: str = field(
        rule=Text(r"(?s).*\.[pP][nN][gG]", "a file name ending in .png"),
        doc="PNG file to write: one row per sample, its tone-mapped render beside its four maps, "
        "labelled with its id, material and lighting.",
        metavar="FILE",
    )
    rows: int = field(
        8,
        rule=Int(*ROWS_RANGE),
        doc="Rows: this many samples, spread evenly over the renders recorded so far.",
        unit="samples",
    )
    tile: int | None = field(
        None,
        rule=Optional(Int(*TILE_RANGE), default_text="the render size, scaled to 128-256"),
        doc="Picture size.",
        unit="pixels",
    )


@dataclass(frozen=True)
class InfoRequest(Checked):
    """`shaderball info`: counts, sizes and completion of a dataset folder, or a spec's plan."""

    directory: str = dataset_operand(
        "A dataset folder, or a spec file (then what `shaderball plan SPEC` prints without timing).",
        "DIR|SPEC",
        "a dataset folder written by `shaderball build`, or a spec file",
    )


def dir_refused(root: str, what: str, allowed: str = DATASET_FOLDER, owner=ValidateRequest):
    """A folder that is not a readable dataset: the ``directory`` field of ``owner``."""
    return owner.field_error("directory", root, allowed, what=f"{format_value(root)} {what}")
