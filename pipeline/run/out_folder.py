"""What a build may write into its folder, checked before anything is: the spec read once,
the folder new or built from the same spec (``--allow-spec-change`` for the fields no sample
depends on), paths short enough for the file system, the same installation as the samples
already there; and the description a build writes. :mod:`pipeline.run.build` runs the build.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable

from pipeline import __version__
from pipeline.check.snapshot import read_snapshot, spec_differences
from pipeline.dataset.plan import PLAN_FORMAT, Plan, plan_summary
from pipeline.dataset.spec import DatasetSpec
from pipeline.dataset.spec_file import (
    parse_spec_bytes,
    read_spec_file,
    source_changes,
    source_file_digests,
    spec_digest,
)
from pipeline.errors import USER_ERRORS, short_repr
from pipeline.fields.rules import format_value
from pipeline.render.mitsuba_env import (
    GUARANTEE_BASIS,
    determinism,
    library_versions,
    machine_fingerprint,
)
from pipeline.run.request import BuildRequest
from pipeline.store.folder import (
    CREATABLE,
    folder_names,
    only_temp_files,
    why_not_creatable,
)
from pipeline.store.layout import Layout
from pipeline.store.records import dumps, read_json

LAYOUT_VERSION = 1
#: Spec fields no sample, file or layout depends on: the only ones --allow-spec-change accepts.
SPEC_FIELDS_FREE_TO_CHANGE = (("dataset", "name"), ("dataset", "version"))


def read_spec_text(spec_path: str) -> tuple[DatasetSpec, str]:
    """The spec at ``spec_path`` and its text, read once: a pipe (``<(cat spec.toml)``,
    /dev/stdin) can be read only once. Relative ``svbrdf_folders`` are taken from the
    spec file's folder, or from the current folder for a pipe."""
    data, base_dir = read_spec_file(spec_path, "SPEC")
    spec = parse_spec_bytes(data, source=spec_path, base_dir=base_dir)
    return spec, data.decode("utf-8-sig")


def _describe_differences(diffs, limit: int = 4) -> str:
    shown = [f"{s}.{k} = {short_repr(o)} in the dataset, {short_repr(n)} in the spec" for s, k, o, n in diffs[:limit]]
    more = f" and {len(diffs) - limit} more" if len(diffs) > limit else ""
    return "; ".join(shown) + more


def _out_refused(out: str, what: str, allowed: str = "a new or empty folder, or a dataset of the same spec"):
    """A refused output folder: ``out``'s field, its value, why (``what``)."""
    return BuildRequest.field_error("out", out, allowed, what=f"{format_value(out)} {what}")


def check_output_dir(out: str, spec: DatasetSpec, allow_spec_change: bool = False) -> str:
    """Refuse an output directory that holds something else.

    Return 'new' (empty, missing, or only temporary files of a build killed before it wrote
    its spec snapshot), 'resume' (same spec) or 'respec' (a change ``allow_spec_change``
    permits: only ``dataset.name`` / ``dataset.version``; the snapshot is then rewritten).
    """
    layout = Layout(out)
    check_path_lengths(out)
    if os.path.lexists(out) and not os.path.exists(out):
        raise _out_refused(
            out, f"is a symbolic link to {format_value(os.readlink(out))}, which does not exist or is a loop of links"
        )
    if os.path.exists(out) and not os.path.isdir(out):
        raise _out_refused(out, "exists and is not a directory")
    try:
        names = folder_names(out)
    except OSError as exc:
        raise _out_refused(out, f"cannot be listed: {exc.strerror}") from None
    if names is None or only_temp_files(names):
        if why := why_not_creatable(out):
            raise _out_refused(out, why, CREATABLE)
        return "new"
    if not os.path.lexists(layout.spec):
        raise _out_refused(
            out,
            f"is not empty and holds no {os.path.basename(layout.spec)}: not a shaderball dataset",
            "choose an empty or new directory",
        )
    try:
        existing = read_snapshot(out)
    except USER_ERRORS as exc:
        raise _out_refused(
            out,
            f"holds an unreadable spec snapshot ({exc})",
            "run `shaderball validate --repair` or choose another directory",
        ) from None
    mode = "resume"
    built = read_json(layout.description)
    changed = source_changes(built.get("sources") if isinstance(built, dict) else None, spec)
    if changed and not spec_differences(existing, spec):
        raise _out_refused(
            out,
            f"holds dataset {format_value(existing.dataset.name)} built from other files: " + "; ".join(changed),
            "restore the files it was built from, or build into a new directory (a changed mesh or map is "
            "another dataset)",
        )
    if spec_digest(existing) != spec_digest(spec):
        diffs = spec_differences(existing, spec)
        blocking = [d for d in diffs if (d[0], d[1]) not in SPEC_FIELDS_FREE_TO_CHANGE]
        if blocking or not allow_spec_change:
            free = " or ".join(f"{s}.{k}" for s, k in SPEC_FIELDS_FREE_TO_CHANGE)
            hint = (
                f"{{allow_spec_change}} accepts a change of {free} only, which no sample depends on"
                if blocking
                else "these fields change no sample: pass {allow_spec_change} to accept them"
            )
            raise _out_refused(
                out,
                f"holds dataset {format_value(existing.dataset.name)} built from a different spec "
                f"(digest {spec_digest(existing)[:12]} vs {spec_digest(spec)[:12]}): "
                f"{_describe_differences(blocking or diffs)}",
                f"resume it with its own spec ({layout.spec}) or build into a new directory; {hint}",
            )
        mode = "respec"
    if not os.access(out, os.W_OK):
        raise _out_refused(out, "is not writable")
    return mode


#: The longest name a build writes below DIR: a texture file's temporary file
#: (pipeline.store.atomic: prefix, 8 random characters, "-", the file's name).
LONGEST_REL = f"shards/s00000/.tmp-xxxxxxxx-{Layout.texture_rel('s00000', 'm000000').rsplit('/', 1)[1]}"


def check_path_lengths(out: str) -> None:
    """Refuse an output folder whose files would have names the filesystem cannot hold
    (ENAMETOOLONG half-way through a build), before anything is written."""
    full = os.path.join(os.path.abspath(out), *LONGEST_REL.split("/"))
    probe = os.path.abspath(out)
    while not os.path.isdir(probe):
        probe = os.path.dirname(probe)
    try:
        name_max, path_max = os.pathconf(probe, "PC_NAME_MAX"), os.pathconf(probe, "PC_PATH_MAX")
    except (OSError, ValueError):
        name_max, path_max = 255, 4096
    long_part = next((part for part in full.split(os.sep) if len(os.fsencode(part)) > name_max), None)
    if long_part is not None:
        raise _out_refused(
            out,
            f"is not allowed: a folder name there is {len(os.fsencode(long_part))} bytes long",
            f"the filesystem allows {name_max}",
        )
    if len(os.fsencode(full)) >= path_max:
        raise _out_refused(
            out,
            f"is not allowed: the dataset's files would have paths of {len(os.fsencode(full))} bytes",
            f"the filesystem allows {path_max - 1}",
        )


def plan_digest(plans: Plan, tick: Callable[[int, int], None] | None = None) -> str:
    """SHA-256 of every planned material and lighting (ids, seeds, angles, sources).

    Streamed: each shard is planned, hashed and dropped (a lazy plan is never held whole);
    ``tick(shards done, shards)`` is called after each shard."""
    digest = hashlib.sha256()
    for done, shard in enumerate(plans, start=1):
        for material in shard.materials:
            digest.update(dumps(material.to_dict()).encode("utf-8"))
        if tick is not None:
            tick(done, len(plans))
    return digest.hexdigest()


def check_same_installation(out: str, plans: Plan, variant: str, digest: str | None = None) -> None:
    """Refuse to resume ``out`` when this installation would make its samples differently.

    The spec snapshot alone cannot tell: a newer shaderball may plan other seeds or angles
    for the same spec, and other Mitsuba/drjit versions or another backend render other
    bytes. Mixing the two in one dataset would go unnoticed, so compare with dataset.json.
    """
    old = read_json(Layout(out).description)
    if not isinstance(old, dict):
        return  # a build killed before its first description: nothing rendered to compare
    differences = []
    digest = digest or plan_digest(plans)
    old_format = old.get("plan_format", 1)
    if old.get("plan_digest") and old_format != PLAN_FORMAT:
        raise _out_refused(
            out,
            f"was planned with plan format {short_repr(old_format)} "
            f"(by shaderball {old.get('shaderball') if isinstance(old.get('shaderball'), str) else 'unknown'}); "
            f"this shaderball ({__version__}) plans format {PLAN_FORMAT} "
            "(sun elevations with the same bits on every machine; docs/spec.md, 'The same plan on every "
            "machine'). Resuming would mix two plans of the spec",
            "build into a new directory, or finish this one with the shaderball that started it",
        )
    if old.get("plan_digest") and old["plan_digest"] != digest:
        differences.append(
            f"this shaderball plans other samples for the same spec (plan digest "
            f"{str(old['plan_digest'])[:12]} in dataset.json, {digest[:12]} now)"
        )
    libraries = library_versions()
    recorded = old.get("libraries") if isinstance(old.get("libraries"), dict) else {}  # dataset.json: any type
    for name in ("mitsuba", "drjit"):
        was = recorded.get(name)
        if was and was != libraries.get(name):
            differences.append(f"{name} {was} in dataset.json, {libraries.get(name)} now")
    if old.get("variant") and old["variant"] != variant:
        differences.append(f"Mitsuba variant {old['variant']} in dataset.json, {variant} now")
    if differences:
        raise _out_refused(
            out,
            f"was built by another installation: {'; '.join(differences)}. Resuming would mix samples made two ways",
            "finish it with the installation that started it, or build into a new directory",
        )


def description(
    spec: DatasetSpec, plans: Plan, variant: str, digest: str | None = None, guarantee: str | None = None
) -> dict:
    """dataset.json; ``guarantee``: the dataset's determinism (default: the variant's)."""
    guarantee = guarantee or determinism(variant)
    return {
        "name": spec.dataset.name,
        "version": spec.dataset.version,
        "layout_version": LAYOUT_VERSION,
        "spec_digest": spec_digest(spec),
        "plan_format": PLAN_FORMAT,
        "plan_digest": digest or plan_digest(plans),
        "shaderball": __version__,
        "libraries": library_versions(),
        "machine": machine_fingerprint(),
        "variant": variant,
        "determinism": {"guarantee": guarantee, "basis": GUARANTEE_BASIS[guarantee]},
        "counts": plan_summary(plans),
        "colorspace": "linear Rec.709 (sRGB primaries, D65 white)",
        # the mesh files and environment maps the spec names, by SHA-256 (none: no key)
        **({"sources": sources} if (sources := source_file_digests(spec)) else {}),
    }


def recorded_guarantee(out: str) -> str | None:
    """The determinism guarantee dataset.json records (None: none, or a folder from before it)."""
    old = read_json(Layout(out).description)
    recorded = old.get("determinism") if isinstance(old, dict) else None
    return recorded.get("guarantee") if isinstance(recorded, dict) else None
