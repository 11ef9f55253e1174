"""Sample records: what the manifest says about each render (schema: docs/manifest.md)."""

from __future__ import annotations

import json
import os

from pipeline.store.atomic import sha256_file
from pipeline.store.bounded_read import file_digest, read_json, resolve_inside

__all__ = ["RUN_DEPENDENT_STATS", "SCHEMA_VERSION", "dumps", "file_entry", "file_ok", "read_json", "without_timings"]

SCHEMA_VERSION = 1
#: Keys of a render's statistics that depend on the run (timings), not on the data.
RUN_DEPENDENT_STATS = ("time_s",)


def file_entry(root: str, rel: str, role: str, sha256: str | None = None) -> dict:
    path = os.path.join(root, *rel.split("/"))
    return {
        "role": role,
        "path": rel,
        "sha256": sha256 or sha256_file(path),
        "bytes": os.path.getsize(path),
    }


def file_ok(root: str, entry, hash_check: bool = True) -> bool:
    """The file of a record's entry is inside ``root`` (pipeline.store.bounded_read.resolve_inside:
    no ``..``, not absolute, through no symbolic link), a regular file with the recorded
    size (and SHA-256). A malformed entry is simply not ok."""
    if (
        not isinstance(entry, dict)
        or not isinstance(entry.get("bytes"), int)
        or not isinstance(entry.get("sha256"), str)
    ):
        return False
    try:
        path = resolve_inside(root, entry.get("path"))
        if not hash_check:
            return os.lstat(path).st_size == entry["bytes"] and os.path.isfile(path)
        size, sha256 = file_digest(path, entry["bytes"])
    except OSError:  # missing, unsafe, larger than recorded
        return False
    return size == entry["bytes"] and sha256 == entry["sha256"]


def dumps(obj) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"))


def without_timings(record: dict) -> dict:
    """A record minus its run-dependent values (for comparing two builds)."""
    out = dict(record)
    stats = record.get("stats", {})
    if isinstance(stats, dict):  # any other type is reported by the record checks, compared as is
        out["stats"] = {k: v for k, v in stats.items() if k not in RUN_DEPENDENT_STATS}
    return out
