"""A spec file: read with bounds (size, nesting), parsed into a :class:`DatasetSpec` whose
sections check themselves (:mod:`pipeline.dataset.spec`), written back in canonical form and
digested; the ``SPEC`` operand of the commands that read one; the rows of the reference page
(docs/spec-fields.md).
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import hashlib
import json
import math
import os
import stat
from dataclasses import fields
from typing import Any

import tomllib

from geometry.meshfile import file_sha256
from geometry.objects import BUILTIN_OBJECTS
from materials.brdf_ref import DEFAULT_MODEL
from pipeline.dataset.spec import ENVIRONMENT_KEYS, SECTIONS, DatasetSpec, LightingSection, SceneSection
from pipeline.dataset.spec_rules import SpecError
from pipeline.errors import ShaderballError, quoted
from pipeline.fields import Checked, FieldError, field
from pipeline.fields.rules import (
    MISSING,
    Path,
    Rule,
    format_value,
)
from pipeline.render.limits import DEFAULT_RR_DEPTH
from sky.environment import list_environment_files

# --------------------------------------------------------------------------- parsing


#: A spec file that is there: the rule of every command's SPEC (and of validate --spec).
SPEC_FILE = Path("a spec file", exists="file")


def spec_operand():
    """The SPEC operand of build, plan and study, declared once."""
    return field(
        rule=SPEC_FILE, doc="The dataset spec (manifests/*.toml; docs/spec.md).", positional=True, metavar="SPEC"
    )


#: Largest spec file read (the paper's spec is ~2 kB; 20,000 svbrdf_folders fit in ~1 MB).
MAX_SPEC_BYTES = 16 << 20
#: Deepest nesting of arrays and tables accepted in a spec (the deepest a spec needs is 2).
MAX_SPEC_NESTING = 32
_UTF8_BOM = b"\xef\xbb\xbf"


def read_spec_file(path: str | os.PathLike, name: str = "spec file") -> tuple[bytes, str]:
    """The one reader of a spec file: its bytes, read once (a pipe such as ``<(cat spec.toml)``
    or /dev/stdin can be read only once), at most MAX_SPEC_BYTES, and the folder its relative
    ``svbrdf_folders`` are taken from (the file's own; the current folder for a pipe).
    ``name`` is what a refusal calls the file (``SPEC``: the command's argument)."""
    path = os.fspath(path)
    try:
        with open(path, "rb") as fh:
            regular = stat.S_ISREG(os.fstat(fh.fileno()).st_mode)
            data = fh.read(MAX_SPEC_BYTES + 1)
    except OSError as exc:
        raise ShaderballError(f"{name}: cannot read {quoted(path)}: {exc.strerror}") from None
    if len(data) > MAX_SPEC_BYTES:
        raise ShaderballError(
            f"{name}: {quoted(path)} is larger than {MAX_SPEC_BYTES} bytes; a spec is a short TOML file (docs/spec.md)"
        )
    return data, os.path.dirname(os.path.abspath(path)) if regular else os.getcwd()


def parse_spec(path: str | os.PathLike) -> DatasetSpec:
    """Read (once, :func:`read_spec_file`) and check the spec file at ``path``."""
    data, base_dir = read_spec_file(path)
    return parse_spec_bytes(data, source=os.fspath(path), base_dir=base_dir)


def parse_spec_bytes(data: bytes, source: str = "<bytes>", base_dir: str | None = None) -> DatasetSpec:
    """Decode (UTF-8; a leading byte-order mark is accepted and dropped) and check spec bytes."""
    if data.startswith(_UTF8_BOM):
        data = data[len(_UTF8_BOM) :]
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ShaderballError(
            f"{source}: not UTF-8 text ({exc.reason} at byte {exc.start}); save the spec as UTF-8"
        ) from None
    return parse_spec_text(text, source=source, base_dir=base_dir)


def _nesting_depth(value) -> int:
    """How deeply lists and tables nest in a parsed spec (iterative: a spec nested thousands
    deep must not overflow Python's stack here either)."""
    worst, stack = 0, [(value, 0)]
    while stack:
        item, depth = stack.pop()
        worst = max(worst, depth)
        children = item.values() if isinstance(item, dict) else item if isinstance(item, list) else ()
        stack.extend((child, depth + 1) for child in children)
    return worst


def parse_spec_text(text: str, source: str = "<string>", base_dir: str | None = None) -> DatasetSpec:
    """Parse and check spec TOML ``text``; ``source`` names it in error messages.

    Relative ``materials.svbrdf_folders`` are taken from ``base_dir`` (default: the
    current folder) and stored absolute.
    """
    too_deep = ShaderballError(
        f"{source}: arrays or tables nested more than {MAX_SPEC_NESTING} levels deep "
        "(a spec needs 3: [section], key, [lo, hi]); docs/spec.md"
    )
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ShaderballError(f"{source}: not valid TOML: {exc}") from None
    except RecursionError:  # tomllib's parser recurses per level of nesting
        raise too_deep from None
    if _nesting_depth(table) > MAX_SPEC_NESTING:
        raise too_deep
    try:
        return _spec_from_table(table, base_dir or os.getcwd())
    except SpecError as exc:
        raise exc.with_source(source) from None


def _spec_from_table(table: dict[str, Any], base_dir: str) -> DatasetSpec:
    for name, value in table.items():
        if name not in SECTIONS:
            raise SpecError(
                name,
                "",
                value,
                "sections are " + ", ".join(f"[{s}]" for s in SECTIONS) + _did_you_mean(name, SECTIONS),
                what="unknown section",
            )
        if not isinstance(value, dict):
            raise SpecError(
                name, "", value, f"[{name}] must be a table of keys", what=f"{format_value(value)} is not a table"
            )
    if "dataset" not in table:
        raise SpecError(
            "dataset",
            "",
            MISSING,
            "a [dataset] section with at least name, seed and materials is required",
            what="missing",
        )
    sections = {}
    for name, cls in SECTIONS.items():
        raw = dict(table.get(name, {}))
        for key in PATH_KEYS.get(name, ()):
            if isinstance(raw.get(key), list):
                raw[key] = [_from_spec_folder(base_dir, f, key) for f in raw[key]]
        sections[name] = _section_from_table(cls, raw)
    return DatasetSpec(**sections)


#: Keys whose items are paths, taken from the spec file's folder when relative.
PATH_KEYS: dict[str, tuple[str, ...]] = {
    "materials": ("svbrdf_folders",),
    "scene": ("objects",),
    "lighting": ("environments",),
}


def _from_spec_folder(base_dir: str, item, key: str):
    """``item`` made absolute from the spec's folder; a built-in object's name stays a name."""
    if not isinstance(item, str) or not item or (key == "objects" and item in BUILTIN_OBJECTS):
        return item
    return os.path.normpath(os.path.join(base_dir, os.path.expanduser(item)))


def _section_from_table(cls: type[Checked], raw: dict[str, Any]) -> Checked:
    known = {f.name: f for f in fields(cls) if f.metadata["in_file"]}
    for key, value in raw.items():
        if key not in known:
            raise SpecError(
                cls.SECTION,
                key,
                value,
                f"[{cls.SECTION}] takes only: " + ", ".join(known) + _did_you_mean(key, known),
                what=f"unknown key (value {format_value(value)}) is not allowed",
            )
    for name, f in known.items():
        if name not in raw and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise SpecError(cls.SECTION, name, MISSING, "required: " + f.metadata["rule"].allowed, what="missing")
    try:
        return cls(**raw)
    except SpecError:
        raise
    except FieldError as exc:  # a section declared outside this module (the renderer's settings)
        raise SpecError(cls.SECTION, exc.name, exc.value, exc.allowed, what=exc.what) from None


def _did_you_mean(word: str, options) -> str:
    close = difflib.get_close_matches(word, list(options), n=1)
    return f" (did you mean {close[0]}?)" if close else ""


# --------------------------------------------------------------------------- canonical form


def spec_to_dict(spec: DatasetSpec) -> dict[str, dict[str, Any]]:
    """Every field of every section, defaults included, as plain TOML/JSON data."""
    return {name: getattr(spec, name).to_dict() for name in SECTIONS}


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"non-finite float {value!r} has no canonical form")
        return repr(value)  # shortest round-tripping form; always has '.', 'e' or both
    if isinstance(value, str):
        # JSON's escapes are TOML's, but TOML refuses surrogate escapes (so no
        # ensure_ascii) and wants DEL escaped (which JSON leaves alone).
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML form for {type(value).__name__}")


def spec_to_toml(spec: DatasetSpec) -> str:
    """The canonical TOML snapshot: every field explicit (but the scene's and the environment's,
    left out at their defaults: :data:`SNAPSHOT_OMITS_AT_DEFAULT`); ``parse_spec_text(it) == spec``."""
    lines = ["# shaderball dataset spec, canonical form: every field explicit.", ""]
    for name, table in _omitting(spec_to_dict(spec), SNAPSHOT_OMITS_AT_DEFAULT).items():
        if not table and name in SNAPSHOT_OMITS_AT_DEFAULT:
            continue
        lines.append(f"[{name}]")
        lines.extend(f"{key} = {_toml_value(value)}" for key, value in table.items())
        lines.append("")
    return "\n".join(lines)


#: Fields added after datasets were first built: left out of the digest while at their
#: default, so a dataset built before they existed keeps its digest (and validates).
DIGEST_OMITS_AT_DEFAULT: dict[str, dict[str, Any]] = {
    "materials": {"model": DEFAULT_MODEL},
    "render": {"sampler": "independent", "rr_depth": DEFAULT_RR_DEPTH, "clamp": 0.0, "target_error": 0.0},
}


#: The scene's and the environment's keys: left out of the snapshot (spec.toml) and the digest
#: while at their default, so a spec that names neither builds the same files as before they
#: existed, spec.toml included.
SNAPSHOT_OMITS_AT_DEFAULT: dict[str, dict[str, Any]] = {
    "scene": SceneSection().to_dict(),
    "lighting": {k: v for k, v in LightingSection().to_dict().items() if k in ENVIRONMENT_KEYS},
}


def _omitting(table: dict[str, dict[str, Any]], omits: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    out = dict(table)
    for section, defaults in omits.items():
        out[section] = {k: v for k, v in out[section].items() if not (k in defaults and v == defaults[k])}
    return out


def spec_digest(spec: DatasetSpec) -> str:
    """SHA-256 (hex) of the canonical JSON form and of the files it names (mesh files and
    environment maps: :func:`source_file_digests`): equal specs on equal files, equal digests."""
    table = _omitting(_omitting(spec_to_dict(spec), DIGEST_OMITS_AT_DEFAULT), SNAPSHOT_OMITS_AT_DEFAULT)
    table = {name: section for name, section in table.items() if section or name not in SNAPSHOT_OMITS_AT_DEFAULT}
    files = source_file_digests(spec)
    if files:
        table["files"] = files
    canonical = json.dumps(table, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)
    return hashlib.sha256(canonical.encode("ascii")).hexdigest()


def source_files(spec: DatasetSpec) -> tuple[str, ...]:
    """The mesh files and environment maps ``spec`` names (folders expanded), sorted."""
    meshes = [o for o in spec.scene.objects if o not in BUILTIN_OBJECTS]
    return tuple(sorted(set(meshes) | set(environment_files(spec))))


def environment_files(spec: DatasetSpec) -> tuple[str, ...]:
    """The environment maps of ``spec``, its files and its folders' files, sorted (absolute paths):
    the list a lighting draws its map from by index."""
    return list_environment_files(spec.lighting.environments) if spec.lighting.environments else ()


def source_file_digests(spec: DatasetSpec) -> dict[str, str]:
    """SHA-256 of each of :func:`source_files` (path -> hex): a changed mesh or map is another
    dataset. Memoised per (path, size, mtime) so a 200 MB mesh is hashed once per process."""
    out = {}
    for path in source_files(spec):
        try:
            st = os.stat(path)
        except OSError as exc:
            raise ShaderballError(f"{quoted(path)}: named by the spec but unreadable: {exc.strerror}") from None
        out[path] = _file_sha256(path, st.st_size, st.st_mtime_ns)
    return out


def source_changes(recorded, spec: DatasetSpec) -> list[str]:
    """What changed in the mesh files and environment maps since ``recorded`` (dataset.json's
    ``sources``: path -> SHA-256) was written: one phrase per file, naming it."""
    if not isinstance(recorded, dict):
        return []
    now = source_file_digests(spec)
    out = []
    for path, digest in sorted(recorded.items()):
        if path not in now:  # gone from a listed folder, or from the spec's list
            gone = "is missing" if not os.path.lexists(path) else "is no longer named by the spec"
            out.append(f"{quoted(path)} {gone}")
        elif now[path] != digest:
            out.append(f"{quoted(path)} changed (SHA-256 {str(digest)[:12]} when built, {now[path][:12]} now)")
    out.extend(f"{quoted(path)} is new to the spec" for path in sorted(set(now) - set(recorded)))
    return out


@functools.lru_cache(maxsize=256)
def _file_sha256(path: str, size: int, mtime_ns: int) -> str:
    return file_sha256(path)  # keyed by size and mtime too: a rewritten file is hashed again


# --------------------------------------------------------------------------- reference


def reference_rows() -> list[tuple[str, str, str, str, str]]:
    """(key, meaning, unit, default, allowed) for every field, for the reference page.

    Static text only (no list read from another package at run time), so the page does
    not change when materials/ or sky/ do.
    """
    rows = []
    for name, cls in SECTIONS.items():
        for f in fields(cls):
            if not f.metadata["in_file"]:
                continue
            rule: Rule = f.metadata["rule"]
            if f.metadata["doc_default"] is not None:
                default = f.metadata["doc_default"]
            elif f.default is not dataclasses.MISSING:
                default = f"`{format_value(rule.plain(f.default))}`"
            else:
                default = "**required**"
            rows.append(
                (
                    f"`{name}.{f.name}`",
                    f.metadata["doc"],
                    f.metadata["unit"] or "-",
                    default,
                    rule.doc_allowed or rule.allowed,
                )
            )
    return rows


def reference_markdown() -> str:
    """The field reference table embedded in docs/spec.md."""
    out = ["| key | meaning | unit | default | allowed |", "|---|---|---|---|---|"]
    for row in reference_rows():
        out.append("| " + " | ".join(c.replace("|", "\\|") for c in row) + " |")
    return "\n".join(out) + "\n"
