"""What `shaderball publish`, `verify` and `unpack` are asked: one checked request each, every
parameter declared once (pipeline.fields); the command line is generated from them.

A refused output folder is a refusal of the request's ``out`` field (:func:`out_refused`),
however the command spells it.
"""

from __future__ import annotations

from dataclasses import dataclass

from pipeline.check.request import dataset_operand
from pipeline.fields import Checked, field, same_as
from pipeline.fields.rules import Bool, Choice, Int, Optional, Path, Text, format_value
from pipeline.publish.publication_facts import LICENSES

#: --shard-bytes: the largest tar shard, from 64 KiB to 1 TiB.
SHARD_BYTES_RANGE = (1 << 16, 1 << 40)
#: Shards of 1 GB: the size the Hugging Face Hub recommends for files of a dataset.
DEFAULT_SHARD_BYTES = 1_000_000_000
DEFAULT_LICENSE = "cc-by-4.0"

_OUT_NEW = "a new or empty folder (nothing in it is overwritten)"


@dataclass(frozen=True)
class PublishRequest(Checked):
    """`shaderball publish`: a validated dataset folder into a publication."""

    directory: str = dataset_operand(exists="folder")
    out: str = field(
        rule=Path(_OUT_NEW),
        doc="New or empty folder for the publication: tar shards, samples.jsonl, README.md (dataset "
        "card), croissant.json, SHA256SUMS (docs/publish.md).",
        metavar="PUB",
    )
    shard_bytes: int = field(
        DEFAULT_SHARD_BYTES,
        rule=Int(*SHARD_BYTES_RANGE),
        doc="Largest tar shard; shards hold whole materials (a larger material gets a shard of its own).",
        unit="bytes",
    )
    license: str = field(
        DEFAULT_LICENSE,
        rule=Choice(tuple(LICENSES)),
        doc="License of the data, as the Hugging Face Hub names it (card and Croissant metadata).",
    )
    url: str | None = field(
        None,
        rule=Optional(Text(r"https?://\S+", "an http(s) URL without spaces"), "unset (none)", default_text="none"),
        doc="Where the publication will live (Croissant's url), e.g. https://huggingface.co/datasets/ORG/NAME.",
    )


@dataclass(frozen=True)
class VerifyRequest(Checked):
    """`shaderball verify`: a publication checked without extracting it."""

    pub: str = field(
        rule=Path("a publication folder written by `shaderball publish`", exists="folder"),
        doc="The publication folder.",
        positional=True,
        metavar="PUB",
    )


@dataclass(frozen=True)
class UnpackRequest(Checked):
    """`shaderball unpack`: a publication restored as a dataset folder."""

    pub: str = same_as(VerifyRequest, "pub", positional=True)
    out: str = field(
        rule=Path(_OUT_NEW),
        doc="New or empty folder for the dataset; left as it was if the publication is refused.",
        metavar="DIR",
    )
    validate: bool = field(
        True,
        rule=Bool(),
        doc="Run `shaderball validate` on the result (it needs the spec's svbrdf_folders, if any, on this machine).",
    )


def out_refused(out: str, allowed: str = _OUT_NEW, owner=PublishRequest):
    """A refused output folder, as the ``out`` field of ``owner`` (publish's or unpack's)."""
    return owner.field_error("out", out, allowed)


__all__ = [
    "DEFAULT_LICENSE",
    "DEFAULT_SHARD_BYTES",
    "SHARD_BYTES_RANGE",
    "PublishRequest",
    "UnpackRequest",
    "VerifyRequest",
    "format_value",
    "out_refused",
]
