"""The one reader of a dataset folder: which files are records, markers, the manifest and
temporary files, and what each shard holds so far (the names: pipeline.store.layout).

Build (progress, resume, the sweep of temporary files), info, preview, validate and the
crash harness read folders through this module, so they agree on what a file is.
"""

from __future__ import annotations

import os
import re

from pipeline.store.atomic import TEMP_PREFIX
from pipeline.store.layout import LOCK_FILE, MANIFEST_FILE, MARKER_FILE, SHARDS_DIR, Layout
from pipeline.store.records import read_json

__all__ = [
    "LOCK_FILE", "MANIFEST_FILE", "MARKER_FILE", "RECORD_NAME", "SHARD_NAME", "TEMP_PREFIX", "disk_usage",
    "is_lock_file", "is_record_file", "is_temp_file", "manifest_record_count", "only_temp_files", "read_manifest",
    "recorded_count", "record_file_names", "remove_temp_files", "shard_ids_on_disk", "shard_records",
]

#: A sample's record file, ``Layout.record_rel``: ``m<6-digit material>_l<light>.json``
#: (MAX_MATERIALS is 1,000,000, so a material index has 6 digits).
RECORD_NAME = re.compile(r"^m\d{6}_l\d+\.json$")
#: A shard folder, ``pipeline.dataset.plan.shard_id``: ``s<5-digit index>`` (MAX_SHARDS 100,000).
SHARD_NAME = re.compile(r"^s\d{5}$")


def is_temp_file(name: str) -> bool:
    """A temporary file of pipeline.store.atomic (a write in progress, or a killed one)."""
    return name.startswith(TEMP_PREFIX)


def is_record_file(name: str) -> bool:
    """A sample's record file (not the marker, not a temporary file)."""
    return RECORD_NAME.match(name) is not None


def is_lock_file(name: str) -> bool:
    """The writer lock (pipeline.store.lock): present while a writer runs, or left unlocked by
    a killed one; no part of the data."""
    return name == LOCK_FILE


def only_temp_files(names) -> bool:
    """Nothing but temporary files and the writer lock: what a build killed before its first
    whole file leaves (such a folder is new to the next build)."""
    return all(is_temp_file(n) or is_lock_file(n) for n in names)


def shard_ids_on_disk(layout: Layout) -> list[str]:
    """The shard folders under ``shards/``, sorted (none when it cannot be listed)."""
    try:
        names = os.listdir(os.path.join(layout.root, SHARDS_DIR))
    except OSError:
        return []
    return sorted(n for n in names if SHARD_NAME.match(n))


def _shard_names(layout: Layout, shard_id: str) -> list[str] | None:
    """The names in a shard's folder, or None when the folder does not exist."""
    try:
        return os.listdir(layout.shard_dir(shard_id))
    except FileNotFoundError:
        return None


def record_file_names(layout: Layout, shard_id: str) -> list[str] | None:
    """The record files of a shard, sorted; None when the shard's folder does not exist."""
    names = _shard_names(layout, shard_id)
    return None if names is None else sorted(n for n in names if is_record_file(n))


def recorded_count(layout: Layout, shard_id: str, planned: int) -> int:
    """Renders of a shard with a record on disk: ``planned`` once it has a marker, else its
    record files (one listing, nothing read: cheap enough for progress)."""
    names = _shard_names(layout, shard_id)
    if names is None:
        return 0
    if MARKER_FILE in names:
        return planned
    return sum(1 for n in names if is_record_file(n))


def shard_records(layout: Layout, shard_id: str) -> tuple[list[dict], bool, bool]:
    """(records, complete, started) of one shard: the marker's, else the record files'."""
    marker = read_json(layout.marker(shard_id))
    if marker and marker.get("complete"):
        return list(marker.get("records", [])), True, True
    names = record_file_names(layout, shard_id)
    if names is None:
        return [], False, False
    records = []
    for name in names:
        record = read_json(os.path.join(layout.shard_dir(shard_id), name))
        if isinstance(record, dict) and "id" in record:
            records.append(record)
    return records, False, True


def read_manifest(layout: Layout) -> bytes:
    """The manifest's bytes (OSError, FileNotFoundError included, when it cannot be read)."""
    with open(layout.manifest, "rb") as fh:
        return fh.read()


def manifest_record_count(layout: Layout) -> int | None:
    """Non-empty lines of the manifest, None when there is none."""
    try:
        data = read_manifest(layout)
    except OSError:
        return None
    return sum(1 for line in data.split(b"\n") if line.strip())


def disk_usage(root: str) -> tuple[int, int]:
    """(bytes of every file under ``root``, count of temporary files)."""
    total = temps = 0
    for folder, _dirs, names in os.walk(root):
        for name in names:
            try:
                total += os.stat(os.path.join(folder, name)).st_size
            except OSError:
                continue
            temps += is_temp_file(name)
    return total, temps


def remove_temp_files(layout: Layout, shard_ids, older_than: float) -> int:
    """Remove the temporary files in DIR and the shards' folders last modified before
    ``older_than`` (wall clock); return the count removed."""
    removed = 0
    for folder in [layout.root] + [layout.shard_dir(s) for s in shard_ids]:
        try:
            entries = list(os.scandir(folder))
        except FileNotFoundError:
            continue
        for entry in entries:
            if not is_temp_file(entry.name):
                continue
            try:
                if entry.stat(follow_symlinks=False).st_mtime < older_than:
                    os.unlink(entry.path)
                    removed += 1
            except FileNotFoundError:
                pass
    return removed
