"""What `shaderball validate` and repair report: the problem kinds, the report and its
JSON and text forms, progress and repair actions."""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field

#: Every problem kind, with what it means (docs/validate.md lists them).
PROBLEM_KINDS: dict[str, str] = {
    "missing_file": "a file a record lists does not exist",
    "size_mismatch": "a file's size differs from its record (truncated, or appended to)",
    "checksum_mismatch": "a file's SHA-256 differs from its record (its bytes changed)",
    "undecodable": "a file cannot be read or is not a readable EXR",
    "bad_layers": "an EXR lacks a layer or has an extra one, or a layer has the wrong channels, size or sample type",
    "non_finite": "NaN or infinite values in maps, or in a render that is not flagged",
    "out_of_range": "map values outside [0, 1], a mask other than 0/1, maps non-zero outside the mask",
    "normal_not_unit": "normals whose length differs from 1 by more than the half-float tolerance",
    "negative_render": "negative values in a render that is not flagged",
    "stats_mismatch": "a record's render statistics differ from the file's pixels or header",
    "missing_sample": "a planned render has no record",
    "extra_sample": "a record for a render the plan does not have",
    "duplicate_record": "a second record for the same render",
    "edited_record": "a record disagrees with the plan, with its files' headers or with the shard marker's copy",
    "extra_file": "a file under DIR that is no part of the dataset",
    "unsafe_path": "a symbolic link, or something that is not a regular file or folder (a FIFO, a "
    "device), under DIR: never followed or read",
    "spec_snapshot": "spec.toml unreadable, or its digest differs from dataset.json's",
    "missing_manifest": "no manifest.jsonl (an unfinished build); records come from the shards",
    "incomplete_shard": "a shard without a complete marker, or a marker missing samples",
}


@dataclass(frozen=True)
class Problem:
    """One thing wrong. ``id``: the sample, material or shard it concerns (None for the
    dataset as a whole); ``path``: the file, relative to DIR with forward slashes."""

    kind: str
    id: str | None
    path: str | None
    message: str

    def to_dict(self) -> dict:
        return {"kind": self.kind, "id": self.id, "path": self.path, "message": self.message}


@dataclass(frozen=True)
class Progress:
    """What a progress callback receives: once per file checked, once per repair step."""

    stage: str  # "check" or "repair"
    done: int
    total: int
    path: str
    bytes_read: int
    elapsed_s: float


@dataclass(frozen=True)
class RepairAction:
    action: str  # delete_extra, regenerate, rerender, rewrite_record, rerun_shard, ...
    path: str | None
    message: str

    def to_dict(self) -> dict:
        return {"action": self.action, "path": self.path, "message": self.message}


@dataclass
class Report:
    """The result of :func:`validate`. Counts are of renders (planned samples)."""

    root: str
    fast: bool
    expected: int
    present: int
    valid: int
    problems: list[Problem]
    flagged: int = 0
    files_checked: int = 0
    bytes_read: int = 0
    seconds: float = 0.0
    # What repair() needs; not part of the JSON report.
    _state: object | None = field(default=None, repr=False, compare=False)  # loading.State

    @property
    def ok(self) -> bool:
        return not self.problems

    @property
    def exit_code(self) -> int:
        """`shaderball validate`'s: 0 for a valid dataset, 1 for an invalid one."""
        return 0 if self.ok else 1

    def counts(self) -> dict[str, int]:
        return dict(Counter(p.kind for p in self.problems))

    def to_dict(self) -> dict:
        return {
            "root": self.root,
            "mode": "fast" if self.fast else "full",
            "ok": self.ok,
            "expected": self.expected,
            "present": self.present,
            "valid": self.valid,
            "flagged": self.flagged,
            "files_checked": self.files_checked,
            "bytes_read": self.bytes_read,
            "seconds": round(self.seconds, 3),
            "problem_counts": self.counts(),
            "problems": [p.to_dict() for p in self.problems],
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=False)

    def lines(self, limit: int = 50) -> list[str]:
        """A human summary: a head line, one line per problem (at most ``limit``), a tally."""
        mode = "fast check (sizes and markers)" if self.fast else "full check"
        head = (
            f"{self.root}: {self.expected} renders expected, {self.present} present, "
            f"{self.valid} valid; {mode} of {self.files_checked} files, "
            f"{self.bytes_read / 1e6:.1f} MB read, {self.seconds:.1f} s"
        )
        if self.ok:
            return [head, "valid: no problems found"]
        out = [head] + [f"{p.kind}: {p.message}" for p in self.problems[:limit]]
        if len(self.problems) > limit:
            out.append(f"... and {len(self.problems) - limit} more")
        tally = ", ".join(f"{kind} {n}" for kind, n in self.counts().items())
        out.append(f"INVALID: {len(self.problems)} problem(s): {tally}")
        return out


class Problems(list):
    def add(self, kind: str, id_: str | None, path: str | None, message: str) -> None:
        self.append(Problem(kind, id_, path, message))


def summarise(messages: list[str], limit: int = 3) -> str:
    text = "; ".join(messages[:limit])
    return text + (f"; and {len(messages) - limit} more" if len(messages) > limit else "")
