"""The types every field of a record (docs/manifest.md) and of a folder's description must
have, checked wherever one is read before any field is used (:func:`field_type_problem`,
:func:`description_problem`), and what makes a record from a marker or a record file usable
(:func:`record_problem`); with how a message names a JSON value (:func:`json_type_name`,
:func:`short_json`)."""

from __future__ import annotations

import json

from pipeline.store.bounded_read import rel_problem
from pipeline.store.layout import SHARDS_DIR

#: JSON type names, as a message says them.
_JSON_NAMES = {dict: "an object", list: "an array", str: "a string", int: "an integer", float: "a number"}
#: A JSON number's Python types (an int where it has no point).
NUMBER = (int, float)
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
    "object": dict,
}
#: Fields inside them that readers use as numbers, strings or containers.
RECORD_SUBFIELDS = {
    "lighting": {
        "elevation_deg": NUMBER,
        "azimuth_deg": NUMBER,
        "turbidity": NUMBER,
        "direction": list,
        "policy": dict,
        "requested": dict,
        "source": str,
        "file": str,
        "sha256": str,
        "rotation_deg": NUMBER,
        "scale": NUMBER,
    },
    "material": {"kind": str, "values": dict},
    "object": {"name": str, "kind": str, "sha256": str, "uv_source": str, "file_sha256": str},
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
    "sources": dict,
}
DESCRIPTION_SUBFIELDS = {
    "counts": {
        "materials": int,
        "renders": int,
        "shards": int,
        "svbrdf": int,
        "uniform": int,
        "svbrdf_sources": dict,
        "objects": dict,
        "environments": list,
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
