"""The one reader of a dataset folder: which files are records, markers, the manifest and
temporary files, what each shard holds so far (the names: pipeline.store.layout), and the
rules for reading anything in it.

Build (progress, resume, the sweep of temporary files), info, preview, validate, the
training loader and the crash harness read folders through this module, so they agree on
what a file is and on what is safe to open.

A dataset folder is untrusted input: anyone may have edited it. So:

- a path named in a manifest, record or marker is opened only through :func:`resolve_inside`:
  a plain relative path (no ``..``, not absolute, no backslash), every component of it inside
  the folder and none a symbolic link; a path that fails is never followed
  (:class:`UnsafePath`);
- files are opened with ``O_NOFOLLOW | O_NONBLOCK`` and read only when they are regular files
  (a FIFO or a device is refused at once, it never blocks), and only within a size bound
  given by every caller (:func:`read_bytes`, the one whole-file reader): the size a record
  gives the file (:class:`Recorded`: a data file is read only at exactly that size), or a
  declared budget where nothing records it (:data:`MAX_JSON_BYTES` for a record, a
  description or a spec; markers and the manifest by the plan's count of renders). A file
  outside its bound is refused before a byte is read (:class:`OverBound`, naming the file,
  its size and the bound): a render grown to 8 GB costs a ``stat``, not 8 GB;
- JSON records and markers are checked for shape before use (:func:`record_problem`,
  :func:`complete_marker`): a marker ``[1]``, a record without ``bytes``, a marker listing no
  files are reported or treated as not done, never a ``KeyError``.

The folder given by the user (DIR itself) may be a symbolic link: that is their choice.
What is checked is everything below it. Between the check of a path and its opening, a
process that can write the folder could swap a component for a link; the last component is
opened with ``O_NOFOLLOW``, the ones before it are not re-checked (a writer with that access
can write the data itself anyway).
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import stat
from collections.abc import Iterator
from dataclasses import dataclass

from pipeline.errors import quoted
from pipeline.store.atomic import TEMP_PREFIX
from pipeline.store.layout import LOCK_FILE, MANIFEST_FILE, MARKER_FILE, SHARDS_DIR, SPEC_FILE, Layout

__all__ = [
    "LOCK_FILE",
    "MANIFEST_FILE",
    "MARKER_FILE",
    "MAX_JSON_BYTES",
    "OverBound",
    "RECORD_NAME",
    "Recorded",
    "SHARD_NAME",
    "TEMP_PREFIX",
    "UnsafePath",
    "complete_marker",
    "disk_usage",
    "file_digest",
    "is_lock_file",
    "is_record_file",
    "is_temp_file",
    "iter_lines",
    "iter_manifest",
    "manifest_record_count",
    "read_line_at",
    "only_temp_files",
    "read_bytes",
    "read_chunks",
    "read_json",
    "read_json_checked",
    "read_json_in",
    "read_manifest",
    "read_spec_snapshot",
    "record_file_names",
    "record_problem",
    "recorded_count",
    "rel_problem",
    "real_dir",
    "remove_temp_files",
    "resolve_inside",
    "shard_ids_on_disk",
    "shard_records",
    "symlinks_and_odd_files",
    "folder_names",
    "walk_folder",
    "is_empty_folder",
    "unsafe_entry",
    "list_bound",
    "marker_records",
]

#: Largest record file, description or spec read from a folder (a record is ~3 kB).
MAX_JSON_BYTES = 1 << 20
#: Largest marker or manifest without a plan to size them by (the paper's 250,000 renders
#: make a ~800 MB manifest).
MAX_LIST_BYTES = 1 << 32


class UnsafePath(OSError):
    """A path that leaves the folder, passes through a symbolic link, or names something that
    is not a regular file, or a file over its size bound: never followed, never read.
    ``strerror`` says which (an OSError, so callers that report unreadable files report it)."""

    def __init__(self, path: str, reason: str):
        super().__init__(errno.EPERM, reason, path)


def list_bound(renders: int | None) -> int:
    """Size bound of a marker or manifest listing ``renders`` records."""
    return MAX_LIST_BYTES if renders is None else 4096 + renders * MAX_JSON_BYTES


def rel_problem(rel) -> str | None:
    """Why ``rel`` is not a plain relative path inside a folder (None when it is)."""
    if not isinstance(rel, str) or not rel:
        return f"{rel!r} is not a path"
    if rel.startswith("/") or "\\" in rel or "\0" in rel or ":" in rel.split("/")[0]:
        return f"{rel!r} is absolute or not a plain relative path"
    if any(part in ("", ".", "..") for part in rel.split("/")):
        return f"{rel!r} leaves the folder or is not a plain relative path ('..', '.' or an empty part)"
    return None


def _kind(mode: int) -> str:
    for test, name in (
        (stat.S_ISLNK, "a symbolic link"),
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISDIR, "a directory"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def resolve_inside(root: str, rel) -> str:
    """The path of ``rel`` (a path a record names, relative to DIR with forward slashes)
    inside ``root``, after checking that it stays there: UnsafePath if it is absolute, has a
    ``..``, or passes through a symbolic link (none is followed). A part that does not exist
    ends the walk: opening the path then fails with FileNotFoundError."""
    problem = rel_problem(rel)
    if problem:
        raise UnsafePath(str(rel), f"{problem}: it is not followed")
    path = root
    for part in rel.split("/"):
        path = os.path.join(path, part)
        try:
            mode = os.lstat(path).st_mode
        except FileNotFoundError:
            break
        except OSError:
            break  # e.g. ENOTDIR: opening it reports the reason
        if stat.S_ISLNK(mode):
            where = os.path.relpath(path, root).replace(os.sep, "/")
            raise UnsafePath(rel, f"{where} is a symbolic link (to {os.readlink(path)!r}): not followed")
    return path


def unsafe_entry(root: str, rel) -> str | None:
    """Why ``rel`` may not be opened inside ``root`` (None when it may)."""
    try:
        resolve_inside(root, rel)
    except UnsafePath as exc:
        return exc.strerror
    return None


@dataclass(frozen=True)
class Recorded:
    """The size a record gives a file, and the file that says so as validate names it
    (``manifest.jsonl``, a marker): a bound :func:`read_bytes` reads the file within only at
    exactly this size (larger, it was grown; smaller, truncated; either way not read)."""

    size: int
    listed_by: str = "its record"


#: What bounds one read: a :class:`Recorded` size, or a budget in bytes (at most this many).
Bound = Recorded | int


class OverBound(UnsafePath):
    """A regular file whose size is not within its bound: not read. ``strerror`` gives its size
    and the bound, in validate's words for a recorded size (``9013 bytes, manifest.jsonl says
    18026: the file was truncated``)."""

    def __init__(self, path: str, size: int, bound: Bound):
        self.size, self.bound = size, bound
        if isinstance(bound, Recorded):
            how = "truncated" if size < bound.size else "grown"
            reason = f"{size} bytes, {bound.listed_by} says {bound.size}: the file was {how}"
        else:
            reason = f"{size} bytes, over the {bound}-byte bound for this file"
        super().__init__(path, reason)


def _limit(bound: Bound) -> int:
    """The most bytes a read within ``bound`` takes; TypeError for anything but a bound (no
    read is unbounded: a caller with no recorded size declares a budget)."""
    if isinstance(bound, Recorded):
        return bound.size
    if isinstance(bound, int) and not isinstance(bound, bool):
        return bound
    raise TypeError(f"a read needs a bound (a Recorded size or a budget in bytes), not {bound!r}")


def _open_regular(path: str, bound: Bound | None) -> tuple[int, int]:
    """(fd, size) of the regular file at ``path``, opened without following a final symbolic
    link and without blocking on a FIFO; UnsafePath when it is not a regular file, OverBound
    when its size is not within ``bound`` (None: the caller bounds what it reads itself)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise UnsafePath(path, "a symbolic link: not followed") from None
        raise
    info = os.fstat(fd)
    if not stat.S_ISREG(info.st_mode):
        os.close(fd)
        raise UnsafePath(path, f"{_kind(info.st_mode)}, not a regular file: not read")
    if bound is not None and (
        info.st_size > _limit(bound) or (isinstance(bound, Recorded) and info.st_size != bound.size)
    ):
        os.close(fd)
        raise OverBound(path, info.st_size, bound)
    return fd, info.st_size


def _chunks(fd: int, path: str, limit: int | None, size: int = 1 << 20):
    total = 0
    while True:
        chunk = os.read(fd, size)
        if not chunk:
            return
        total += len(chunk)
        if limit is not None and total > limit:
            raise UnsafePath(path, f"grew past the {limit}-byte bound for this file while read: not read")
        yield chunk


def read_bytes(path: str, bound: Bound) -> bytes:
    """The bytes of the regular file at ``path``, if its size is within ``bound``: the size a
    record gives it (:class:`Recorded`: exactly that) or a budget (at most that many bytes).
    The one whole-file reader of a dataset, publication, run or report file: a file outside
    its bound is refused before anything is read (:class:`OverBound`), a file that grows while
    read too; not through a final symbolic link, never from a FIFO or a device (UnsafePath).
    FileNotFoundError and other OSErrors pass through."""
    limit = _limit(bound)
    fd, _size = _open_regular(path, bound)
    try:
        return b"".join(_chunks(fd, path, limit))
    finally:
        os.close(fd)


def read_chunks(path: str, bound: Bound) -> Iterator[bytes]:
    """The bytes of the regular file at ``path`` a chunk at a time, as :func:`read_bytes`
    reads them (opened by the call: OSErrors are raised by it)."""
    limit = _limit(bound)
    fd, _size = _open_regular(path, bound)

    def chunks():
        try:
            yield from _chunks(fd, path, limit)
        finally:
            os.close(fd)

    return chunks()


def file_digest(path: str, bound: Bound) -> tuple[int, str]:
    """(size, SHA-256 hex) of the regular file at ``path``, read as :func:`read_bytes` reads
    (streamed: a large render is not held in memory)."""
    limit = _limit(bound)
    fd, _size = _open_regular(path, bound)
    digest, size = hashlib.sha256(), 0
    try:
        for chunk in _chunks(fd, path, limit):
            digest.update(chunk)
            size += len(chunk)
    finally:
        os.close(fd)
    return size, digest.hexdigest()


#: What one record may hold, counted in its bytes before it is parsed: arrays and objects
#: (``[``, ``{``) and values (``,``, ``:``); a record of the smoke dataset holds 26 and 179.
#: Parsing ``[[],[],...]`` costs ~30 times its size in memory: a parse is bounded by the
#: structure of what is parsed, not only by its size (a bracket inside a string counts too:
#: the count can only be too high).
RECORD_CONTAINERS = 256
RECORD_VALUES = 4096


def structure_problem(data: bytes, records: int = 1) -> str | None:
    """Why ``data`` holds more JSON structure than ``records`` records may (None if not)."""
    containers = data.count(b"[") + data.count(b"{")
    values = data.count(b",") + data.count(b":")
    if containers <= RECORD_CONTAINERS * records and values <= RECORD_VALUES * records:
        return None
    return (
        f"{containers} JSON arrays/objects and {values} values, more than {records} record(s) may hold "
        f"(at most {RECORD_CONTAINERS} and {RECORD_VALUES} each): not parsed"
    )


def read_json_checked(path: str, limit: int = MAX_JSON_BYTES):
    """(value, None) for a readable JSON file, else (None, why: 'missing', 'a FIFO, ...').
    Its structure is bounded by its size bound: one record's per :data:`MAX_JSON_BYTES`."""
    try:
        data = read_bytes(path, limit)
    except FileNotFoundError:
        return None, "missing"
    except OSError as exc:
        return None, exc.strerror or str(exc)
    too_much = structure_problem(data, -(-limit // MAX_JSON_BYTES) + 1)
    if too_much:
        return None, too_much
    try:
        return json.loads(data.decode("utf-8")), None
    except (UnicodeDecodeError, ValueError) as exc:
        return None, f"not JSON (torn or edited: {exc})"
    except RecursionError:
        return None, "not JSON this reader accepts (nested too deeply)"


def read_json(path: str, limit: int = MAX_JSON_BYTES):
    """A JSON file's content, or None when it is missing, torn, unsafe or over ``limit``."""
    return read_json_checked(path, limit)[0]


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


#: JSON type names, as a message says them.
_JSON_NAMES = {dict: "an object", list: "an array", str: "a string", int: "an integer", float: "a number"}
_NUMBER = (int, float)
#: The type of every field a record carries (docs/manifest.md), checked wherever a record is
#: read (manifest, marker, record file, publication) before any field is used: a field may
#: be absent (what is missing is reported by the checks that need it), never of another type.
RECORD_FIELDS = {
    "id": str,
    "material_id": str,
    "shard": str,
    "material_index": int,
    "light_index": int,
    "schema": int,
    "files": list,
    "lighting": dict,
    "lighting_vector": list,
    "material": dict,
    "render": dict,
    "seeds": dict,
    "effects": dict,
    "stats": dict,
}
#: Fields inside them that readers use as numbers, strings or containers.
RECORD_SUBFIELDS = {
    "lighting": {
        "elevation_deg": _NUMBER,
        "azimuth_deg": _NUMBER,
        "turbidity": _NUMBER,
        "direction": list,
        "policy": dict,
        "requested": dict,
    },
    "material": {"kind": str, "values": dict},
    "render": {"spp": int, "resolution": int, "max_depth": int, "integrator": str, "variant": str, "sun": str},
    "seeds": {"light": int, "material": int, "render": int, "render_used": int},
}
#: A file entry of ``files``.
FILE_ENTRY_FIELDS = {"role": str, "path": str, "bytes": int, "sha256": str}


def json_type_name(value) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true/false"
    return next((name for kind, name in _JSON_NAMES.items() if isinstance(value, kind)), type(value).__name__)


def _type_problem(where: str, value, kind) -> str | None:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if isinstance(value, bool) or not isinstance(value, kinds):
        wanted = " or ".join(_JSON_NAMES[k] for k in kinds)
        return f"{where} is {json_type_name(value)} ({short_json(value)}), not {wanted}"
    return None


def short_json(value, limit: int = 40) -> str:
    text = json.dumps(value, sort_keys=True, ensure_ascii=True)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def field_type_problem(record) -> str | None:
    """Why a record's fields cannot be used as their types (:data:`RECORD_FIELDS`,
    :data:`RECORD_SUBFIELDS`, :data:`FILE_ENTRY_FIELDS`), or None. Naming the field, its
    type and value: ``stats is an array ([]), not an object``."""
    if not isinstance(record, dict):
        return f"not a record (a JSON {json_type_name(record)}, not an object)"
    problem = _fields_problem(record, RECORD_FIELDS, RECORD_SUBFIELDS)
    if problem:
        return problem
    for index, entry in enumerate(record.get("files", [])):
        if not isinstance(entry, dict):
            return f"files[{index}] is {json_type_name(entry)}, not an object"
        for name, kind in FILE_ENTRY_FIELDS.items():
            if name in entry:
                problem = _type_problem(f"files[{index}].{name}", entry[name], kind)
                if problem:
                    return problem
    return None


#: The type of every field ``dataset.json`` carries (docs/manifest.md); absent is allowed.
DESCRIPTION_FIELDS = {
    "name": str,
    "version": str,
    "shaderball": str,
    "spec_digest": str,
    "plan_digest": str,
    "plan_format": int,
    "layout_version": int,
    "variant": str,
    "colorspace": str,
    "counts": dict,
    "determinism": dict,
    "libraries": dict,
    "machine": dict,
}
DESCRIPTION_SUBFIELDS = {
    "counts": {
        "materials": int,
        "renders": int,
        "shards": int,
        "svbrdf": int,
        "uniform": int,
        "svbrdf_sources": dict,
    },
}


def description_problem(description) -> str | None:
    """Why ``dataset.json``'s fields cannot be used as their types, or None."""
    if not isinstance(description, dict):
        return f"not a JSON object (a JSON {json_type_name(description)})"
    return _fields_problem(description, DESCRIPTION_FIELDS, DESCRIPTION_SUBFIELDS)


def _fields_problem(obj: dict, fields: dict, subfields: dict) -> str | None:
    """The first field of ``obj`` (or of one of its objects named in ``subfields``, checked
    after its own type) that is not of its type; absent fields are allowed."""
    for key, kind in fields.items():
        if key in obj:
            problem = _type_problem(key, obj[key], kind)
            if problem:
                return problem
    for key, inner in subfields.items():
        for name, kind in inner.items():
            if name in obj.get(key, {}):
                problem = _type_problem(f"{key}.{name}", obj[key][name], kind)
                if problem:
                    return problem
    return None


def record_problem(record, shard_id: str | None = None) -> str | None:
    """Why ``record`` (from a marker or a record file) cannot be used, or None: a JSON
    object with a string ``id`` and a list ``files`` of entries, each a ``role``, a plain
    relative ``path`` (inside ``shards/<shard_id>/`` when given), an integer ``bytes`` and a
    ``sha256`` string, with a ``render`` among them."""
    if not isinstance(record, dict):
        return f"not a record (a JSON {type(record).__name__}, not an object)"
    if not isinstance(record.get("id"), str):
        return "a record without an id"
    problem = field_type_problem(record)
    if problem:
        return f"record {record['id']}: {problem}"
    files = record.get("files")
    if not isinstance(files, list) or not files:
        return f"record {record['id']}: no files listed"
    for entry in files:
        if not isinstance(entry, dict):
            return f"record {record['id']}: a file entry that is not an object"
        missing = [
            key
            for key, kind in (("role", str), ("path", str), ("bytes", int), ("sha256", str))
            if not isinstance(entry.get(key), kind) or isinstance(entry.get(key), bool)
        ]
        if missing:
            return f"record {record['id']}: a file entry without {', '.join(missing)}"
        problem = rel_problem(entry["path"])
        if problem:
            return f"record {record['id']}: file path {problem}"
        if shard_id is not None and not entry["path"].startswith(f"{SHARDS_DIR}/{shard_id}/"):
            return f"record {record['id']}: file path {entry['path']!r} is not in its shard's folder"
    if not any(entry["role"] == "render" for entry in files):
        return f"record {record['id']}: no render file listed"
    return None


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


#: Bytes read at a time by :func:`iter_lines`: a few records' worth, so what a reader of lines
#: holds does not grow with the file up to a larger chunk.
LINE_CHUNK = 1 << 16


def iter_lines(path: str, bound: Bound) -> Iterator[tuple[int, int, bytes]]:
    """(line number from 1, byte offset, bytes without the newline) of every line of the
    regular file at ``path``, read a chunk at a time (as :func:`read_bytes` reads: no link, no
    FIFO, within ``bound``, OverBound beyond), so only one line is held at a time.
    The file is opened before the first line is asked for: OSErrors are raised by the call."""
    limit = _limit(bound)
    fd, _size = _open_regular(path, bound)
    return _lines_of(fd, path, limit)


def _lines_of(fd: int, path: str, limit: int | None) -> Iterator[tuple[int, int, bytes]]:
    number, offset, parts = 0, 0, []  # parts: the line so far (a long line is not re-copied per chunk)
    try:
        for chunk in _chunks(fd, path, limit, LINE_CHUNK):
            start = 0
            while (end := chunk.find(b"\n", start)) >= 0:
                line = b"".join([*parts, chunk[start:end]]) if parts else chunk[start:end]
                parts = []
                number += 1
                yield number, offset, line
                offset += len(line) + 1
                start = end + 1
            if start < len(chunk):
                parts.append(chunk[start:])
        if parts:
            yield number + 1, offset, b"".join(parts)
    finally:
        os.close(fd)


def iter_manifest(layout: Layout, renders: int | None = None) -> Iterator[tuple[int, int, bytes]]:
    """:func:`iter_lines` of the manifest, bounded as :func:`read_manifest` bounds it."""
    return iter_lines(layout.manifest, list_bound(renders))


def read_line_at(path: str, offset: int, limit: int) -> bytes:
    """The line of the regular file at ``path`` that starts at byte ``offset`` (a line
    :func:`iter_lines` found), without its newline; at most ``limit`` bytes are read."""
    fd, _size = _open_regular(path, None)
    try:
        data = os.pread(fd, limit + 1, offset)
    finally:
        os.close(fd)
    return data.split(b"\n", 1)[0]


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
            what = _kind(mode)
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
