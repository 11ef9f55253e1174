"""The one reader of a dataset folder: which files are records, markers, the manifest and
temporary files, what each shard holds so far (the names: pipeline.store.layout), and the
rules for reading anything in it.

Build (progress, resume, the sweep of temporary files), info, preview, validate, the
training loader and the crash harness read folders through this module, so they agree on
what a file is and on what is safe to open.

A dataset folder is untrusted input: anyone may have edited it. A path in it is opened, and a
file read, only within a bound (pipeline.store.bounded_read); JSON records and markers are
checked for shape before use (:func:`~pipeline.store.record_fields.record_problem`,
:func:`complete_marker`): a marker ``[1]``, a record without ``bytes``, a marker listing no
files are reported or treated as not done, never a ``KeyError`` (the fields' types:
pipeline.store.record_fields).
"""

from __future__ import annotations

import os
import re
import stat
from collections.abc import Iterator

from pipeline.errors import quoted
from pipeline.store.atomic import TEMP_PREFIX
from pipeline.store.bounded_read import (
    MAX_JSON_BYTES,
    UnsafePath,
    file_kind,
    iter_lines,
    list_bound,
    read_bytes,
    read_json_checked,
    resolve_inside,
)
from pipeline.store.layout import LOCK_FILE, MANIFEST_FILE, MARKER_FILE, SHARDS_DIR, SPEC_FILE, Layout
from pipeline.store.record_fields import record_problem

__all__ = [
    "LOCK_FILE",
    "MANIFEST_FILE",
    "MARKER_FILE",
    "RECORD_NAME",
    "SHARD_NAME",
    "TEMP_PREFIX",
    "complete_marker",
    "disk_usage",
    "is_lock_file",
    "is_record_file",
    "is_temp_file",
    "iter_manifest",
    "manifest_record_count",
    "only_temp_files",
    "read_json_in",
    "read_manifest",
    "read_spec_snapshot",
    "record_file_names",
    "recorded_count",
    "real_dir",
    "remove_temp_files",
    "shard_ids_on_disk",
    "shard_records",
    "symlinks_and_odd_files",
    "folder_names",
    "walk_folder",
    "is_empty_folder",
    "marker_records",
]


def read_json_in(layout: Layout, rel: str, limit: int = MAX_JSON_BYTES):
    """(value, why) of the JSON file at ``rel`` inside the folder, as :func:`read_json_checked`,
    after :func:`resolve_inside` (a marker under a ``shards`` that is a link is not read)."""
    try:
        path = resolve_inside(layout.root, rel)
    except UnsafePath as exc:
        return None, exc.strerror
    return read_json_checked(path, limit)


def read_spec_snapshot(layout: Layout) -> bytes:
    """DIR/spec.toml's bytes (a regular file, bounded); OSError (UnsafePath included) if not."""
    return read_bytes(os.path.join(layout.root, SPEC_FILE), MAX_JSON_BYTES)


def complete_marker(
    layout: Layout, shard_id: str, sample_ids: list[str] | None = None, renders: int | None = None
) -> list[dict] | None:
    """The records of ``shard_id``'s marker when it marks the shard complete and is
    well-formed (:func:`marker_records`); else None: a build then runs the shard again,
    verifying each sample."""
    bound = list_bound(renders if renders is not None else (len(sample_ids) if sample_ids is not None else None))
    return marker_records(read_json_in(layout, Layout.marker_rel(shard_id), bound)[0], shard_id, sample_ids)


def marker_records(marker, shard_id: str, sample_ids: list[str] | None = None) -> list[dict] | None:
    """``marker``'s records if it marks ``shard_id`` complete, its sample list equals its
    records' ids (and ``sample_ids`` when given), and every record is usable
    (:func:`record_problem`); else None."""
    if not isinstance(marker, dict) or marker.get("complete") is not True or marker.get("shard") != shard_id:
        return None
    records = marker.get("records")
    if not isinstance(records, list) or any(record_problem(r, shard_id) for r in records):
        return None
    ids = [r["id"] for r in records]
    if marker.get("samples") != ids or (sample_ids is not None and ids != list(sample_ids)):
        return None
    return records


def is_temp_file(name: str) -> bool:
    """A temporary file of pipeline.store.atomic (a write in progress, or a killed one)."""
    return name.startswith(TEMP_PREFIX)


def is_record_file(name: str) -> bool:
    """A sample's record file (not the marker, not a temporary file)."""
    return RECORD_NAME.match(name) is not None


#: A sample's record file, ``Layout.record_rel``: ``m<6-digit material>_l<light>.json``
#: (MAX_MATERIALS is 1,000,000, so a material index has 6 digits).
RECORD_NAME = re.compile(r"^m\d{6}_l\d+\.json\Z", re.ASCII)
#: A shard folder, ``pipeline.dataset.plan.shard_id``: ``s<5-digit index>`` (MAX_SHARDS 100,000).
SHARD_NAME = re.compile(r"^s\d{5}\Z", re.ASCII)


def is_lock_file(name: str) -> bool:
    """The writer lock (pipeline.store.lock): present while a writer runs, or left unlocked by
    a killed one; no part of the data."""
    return name == LOCK_FILE


def only_temp_files(names) -> bool:
    """Nothing but temporary files and the writer lock: what a build killed before its first
    whole file leaves (such a folder is new to the next build)."""
    return all(is_temp_file(n) or is_lock_file(n) for n in names)


def real_dir(path: str) -> bool:
    """``path`` is a directory and not a symbolic link to one."""
    try:
        return stat.S_ISDIR(os.lstat(path).st_mode)
    except OSError:
        return False


def shard_ids_on_disk(layout: Layout) -> list[str]:
    """The shard folders under ``shards/``, sorted (none when it cannot be listed, or is a
    symbolic link: never followed)."""
    shards = os.path.join(layout.root, SHARDS_DIR)
    if not real_dir(shards):
        return []
    try:
        names = os.listdir(shards)
    except OSError:
        return []
    return sorted(n for n in names if SHARD_NAME.match(n) and real_dir(os.path.join(shards, n)))


def _shard_names(layout: Layout, shard_id: str) -> list[str] | None:
    """The names in a shard's folder, or None when there is no such folder (or the folder, or
    ``shards/``, is a symbolic link: never followed)."""
    folder = layout.shard_dir(shard_id)
    if not (real_dir(os.path.dirname(folder)) and real_dir(folder)):
        return None
    try:
        return os.listdir(folder)
    except OSError:
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


def shard_records(
    layout: Layout, shard_id: str, renders: int | None = None
) -> tuple[list[dict], bool, bool, list[str]]:
    """(records, complete, started, problems) of one shard: the marker's records when it is
    complete and well-formed, else the usable record files'. ``problems`` says, one line
    each, what was left out and why (a torn or malformed marker, a record without files, a
    path leaving the folder); nothing here raises on a malformed file."""
    rel = Layout.marker_rel(shard_id)
    problems = []
    names = _shard_names(layout, shard_id)
    folder = layout.shard_dir(shard_id)
    if names is None:
        if os.path.lexists(folder) or os.path.islink(os.path.dirname(folder)):
            return [], False, False, [f"{SHARDS_DIR}/{shard_id}: a symbolic link or not a folder: not followed"]
        return [], False, False, []
    if MARKER_FILE in names:
        marker, why = read_json_checked(layout.marker(shard_id), list_bound(renders))
        records = marker_records(marker, shard_id) if why is None else None
        if records is not None:
            return records, True, True, []
        problems.append(f"{rel}: {why or _marker_problem(marker, shard_id)}; the shard counts as not complete")
    records = []
    for name in sorted(n for n in names if is_record_file(n)):
        record, why = read_json_checked(os.path.join(folder, name))
        problem = why or record_problem(record, shard_id)
        if problem:
            problems.append(f"{SHARDS_DIR}/{shard_id}/{name}: {problem}; left out")
            continue
        records.append(record)
    return records, False, True, problems


def _marker_problem(marker, shard_id: str) -> str:
    if not isinstance(marker, dict):
        return f"not a marker (a JSON {type(marker).__name__}, not an object)"
    if marker.get("complete") is not True:
        return "does not mark the shard complete"
    if marker.get("shard") != shard_id:
        return f"names shard {marker.get('shard')!r}"
    records = marker.get("records")
    if not isinstance(records, list):
        return "holds no list of records"
    for index, record in enumerate(records):
        problem = record_problem(record, shard_id)
        if problem:
            return f"record {index}: {problem}"
    return "its sample list disagrees with its records"


def read_manifest(layout: Layout, renders: int | None = None) -> bytes:
    """The manifest's bytes: a regular file, at most :func:`list_bound` of ``renders``
    (OSError, FileNotFoundError and UnsafePath included, when it cannot be read)."""
    return read_bytes(layout.manifest, list_bound(renders))


def iter_manifest(layout: Layout, renders: int | None = None) -> Iterator[tuple[int, int, bytes]]:
    """:func:`iter_lines` of the manifest, bounded as :func:`read_manifest` bounds it."""
    return iter_lines(layout.manifest, list_bound(renders))


def manifest_record_count(layout: Layout, renders: int | None = None) -> int | None:
    """Non-empty lines of the manifest, None when there is none (or it cannot be read);
    streamed, a line at a time."""
    try:
        return sum(1 for _n, _o, line in iter_manifest(layout, renders) if line.strip())
    except OSError:
        return None


def disk_usage(root: str) -> tuple[int, int]:
    """(bytes of every file under ``root``, count of temporary files); links are counted as
    links, never followed."""
    total = temps = 0
    for folder, _dirs, names in os.walk(root):
        for name in names:
            try:
                total += os.lstat(os.path.join(folder, name)).st_size
            except OSError:
                continue
            temps += is_temp_file(name)
    return total, temps


def folder_names(path: str) -> list[str] | None:
    """The names in the folder ``path``; None when it is not a folder (OSError when it cannot
    be listed)."""
    return os.listdir(path) if os.path.isdir(path) else None


def walk_folder(root: str, skip=frozenset()) -> Iterator[tuple[str, list[str], list[str]]]:
    """(folder relative to ``root``, "" or ending in "/"; its sub-folders; its other entries),
    names sorted, for every folder under ``root``, top down. Entries whose relative path is in
    ``skip`` (the links and odd entries of :func:`symlinks_and_odd_files`) are left out and
    never entered."""
    for folder, subdirs, names in os.walk(root):
        rel_dir = os.path.relpath(folder, root).replace(os.sep, "/")
        rel_dir = "" if rel_dir == "." else rel_dir + "/"
        subdirs[:] = sorted(name for name in subdirs if rel_dir + name not in skip)
        yield rel_dir, list(subdirs), sorted(name for name in names if rel_dir + name not in skip)


def is_empty_folder(root: str, rel: str) -> bool:
    """Whether the folder ``rel`` (as :func:`walk_folder` names it) under ``root`` holds nothing."""
    return not os.listdir(os.path.join(root, *rel.split("/")))


def symlinks_and_odd_files(root: str) -> list[tuple[str, str]]:
    """(path relative to ``root``, what it is) of every symbolic link and every entry that is
    neither a regular file nor a directory under ``root`` (none is followed)."""
    out = []
    for folder, dirs, names in os.walk(root):
        dirs.sort()
        for name in sorted(dirs + names):
            path = os.path.join(folder, name)
            try:
                mode = os.lstat(path).st_mode
            except OSError:
                continue
            if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
                continue
            rel = os.path.relpath(path, root).replace(os.sep, "/")
            what = file_kind(mode)
            if stat.S_ISLNK(mode):
                try:
                    what += f" (to {os.readlink(path)!r})"
                except OSError:
                    pass
            out.append((rel, what))
    return out


def remove_temp_files(layout: Layout, shard_ids, older_than: float) -> int:
    """Remove the temporary files in DIR and the shards' folders last modified before
    ``older_than`` (wall clock); return the count removed. A shard folder that is a symbolic
    link is not entered."""
    removed = 0
    for folder in [layout.root] + [layout.shard_dir(s) for s in shard_ids]:
        if folder != layout.root and not (real_dir(os.path.dirname(folder)) and real_dir(folder)):
            continue
        try:
            entries = list(os.scandir(folder))
        except OSError:
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


def record_stamps(layout: Layout, shard_ids) -> dict[str, tuple[int, int]]:
    """(inode, mtime in ns) of every record file now in the shards ``shard_ids`` (absent: none).

    A build compares them afterwards to count the records it wrote: an atomic write makes a
    new inode, whatever the clock says, so a copy made a second before the build (a fresh
    mtime) is not mistaken for a render of this build.
    """
    stamps = {}
    for shard_id in shard_ids:
        for name in record_file_names(layout, shard_id) or []:
            path = os.path.join(layout.shard_dir(shard_id), name)
            try:
                st = os.stat(path, follow_symlinks=False)
            except FileNotFoundError:
                continue
            stamps[path] = (st.st_ino, st.st_mtime_ns)
    return stamps


#: What an output folder that cannot be made is refused for wanting (every command alike).
CREATABLE = "a folder that can be created"


def why_not_creatable(out: str) -> str | None:
    """Why an output folder cannot be made (below a file or a dangling link, or in a folder
    this process cannot write), or None; each command refuses it as its own output's field."""
    probe = os.path.abspath(out)
    while not os.path.lexists(probe):
        probe = os.path.dirname(probe)
    if not os.path.isdir(probe):
        what = "a dangling symbolic link" if os.path.islink(probe) else "a file"
        return f"cannot be created: {quoted(probe)} is {what}, not a folder"
    if not os.access(probe, os.W_OK):
        return f"cannot be created: {probe} is not writable"
    return None
