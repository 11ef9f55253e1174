"""Why a publication is refused, and the caps that bound what reading one may cost."""

from __future__ import annotations

from dataclasses import dataclass

from pipeline.errors import ShaderballError
from pipeline.store.bounded_read import MAX_JSON_BYTES, RECORD_CONTAINERS, RECORD_VALUES


class Refused(ShaderballError):
    """A publication (or the dataset to publish) that is not accepted: exit code 1.

    ``kind`` names the reason in a word (``dotdot``, ``member_checksum``, ...); the message names the file,
    the member and what was expected.
    """

    exit_code = 1

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.kind = kind
        self.message = message

    def to_dict(self) -> dict:
        return {"kind": self.kind, "message": self.message}


@dataclass(frozen=True)
class Limits:
    """Caps checked before anything is read into memory or written (docs/publish.md)."""

    #: one tar member (a 4096x4096 float32 render is 201 MB uncompressed)
    member_bytes: int = 1 << 30
    #: members over all tars (the paper's spec: 120,000)
    members: int = 10_000_000
    #: every file of PUB together
    total_bytes: int = 1 << 44
    #: one plain file of PUB read into memory (manifest, samples table, ...)
    text_bytes: int = 1 << 30
    #: files and folders under PUB
    entries: int = 1_000_000
    #: an EXR header (attributes), and its image's width or height
    exr_header_bytes: int = 1 << 20
    exr_side: int = 4096
    #: one record (a manifest line, a record member): bytes, JSON arrays and objects, values
    #: (commas and colons); a record of the smoke dataset has 2.4 kB, 26 and 179. Counted in
    #: the bytes before anything is parsed: parsing costs up to ~30x the text in memory, so
    #: what a parse may cost is bounded by the structure, not only by the size
    record_bytes: int = MAX_JSON_BYTES
    record_containers: int = RECORD_CONTAINERS
    record_values: int = RECORD_VALUES
    #: any other JSON file (publication.json, croissant.json, dataset.json), per file it
    #: lists (SHA256SUMS' lines), on top of a fixed allowance
    json_containers_per_file: int = 64
    json_values_per_file: int = 512


DEFAULT_LIMITS = Limits()


def refuse_invalid(report, subject: str, outcome: str) -> None:
    """Refused (``invalid_dataset``) when ``report``, pipeline.check.validate's, has problems:
    ``subject`` does not pass validate, its first three problems, then ``outcome``."""
    if not report.ok:
        first = "; ".join(p.message for p in report.problems[:3])
        raise Refused(
            "invalid_dataset",
            f"{subject} does not pass `shaderball validate` ({len(report.problems)} problem(s): {first}); {outcome}",
        )
