"""Sample records: what the manifest says about each render (schema: docs/manifest.md)."""

from __future__ import annotations

import json
import os

from pipeline.store.atomic import sha256_file

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


def file_ok(root: str, entry: dict, hash_check: bool = True) -> bool:
    """The file of a record's entry exists with the recorded size (and SHA-256)."""
    path = os.path.join(root, *entry["path"].split("/"))
    try:
        if os.path.getsize(path) != entry["bytes"]:
            return False
    except OSError:
        return False
    return not hash_check or sha256_file(path) == entry["sha256"]


def read_json(path: str):
    """A JSON file's content, or None when it is missing or torn."""
    try:
        with open(path, encoding="utf-8") as fh:
            return json.load(fh)
    except (OSError, ValueError):
        return None


def dumps(obj) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"))


def without_timings(record: dict) -> dict:
    """A record minus its run-dependent values (for comparing two builds)."""
    out = dict(record)
    out["stats"] = {k: v for k, v in record.get("stats", {}).items() if k not in RUN_DEPENDENT_STATS}
    return out
