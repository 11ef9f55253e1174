"""What a publication says of a sample's scene: the object its material was rendered on and
the light (the sun and sky, or an HDR environment map), as columns of ``samples.jsonl``
(:func:`scene_values`) and checks of a record's scene fields (:func:`scene_problem`).

Only a publication of a dataset whose spec names other objects or environment maps has these
columns (:func:`has_scene_columns`: its ``dataset.json`` counts them); a shaderball-and-sun
publication is byte for byte what it was before objects existed. Where a publication has them,
every row has every one (null where it does not apply), so a table reader sees one schema.

Meshes and maps travel **by digest**, never in the publication: a record carries the canonical
mesh's SHA-256 (and the mesh file's) and the map file's SHA-256. Third-party meshes and HDRIs
carry their own licences (a dataset's publisher may not be allowed to redistribute them), a map
is large (a float 4096 x 2048 map is about 100 MB), and the renders and geometry layers (``geometry_normal``,
``depth``, ``mask``) already hold what training needs; a user who has the files checks them
against the digests (the card says how: pipeline.publish.scene_card).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from pipeline.dataset.spec import LIGHT_SOURCES
from pipeline.store.record_fields import json_type_name, short_json

#: The shaderball's name where a record names no object (a spec naming the shaderball alone:
#: its records are as they were before other objects existed).
SHADERBALL = "shaderball"
#: The light of a record whose lighting names no source: the sun and sky.
SUN_SKY, ENVIRONMENT = LIGHT_SOURCES

#: The scene's columns (column, Croissant data type, meaning), after the table's own.
SCENE_COLUMN_DOCS = (
    (
        "object",
        "sc:Text",
        "the object the material was rendered on: shaderball, sphere, rounded_cube, torus, or a mesh file's base name",
    ),
    ("object_kind", "sc:Text", "shaderball, primitive (built in) or mesh (a user's file)"),
    (
        "object_sha256",
        "sc:Text",
        "SHA-256 of the object's canonical mesh (the shaderball's: its parameters' digest); null where no record names it",
    ),
    ("object_file_sha256", "sc:Text", "SHA-256 of the mesh file's bytes (mesh objects only): check a copy against it"),
    ("object_uv_source", "sc:Text", "where the object's UVs come from: built-in, file (the mesh's own) or xatlas"),
    (
        "light_source",
        "sc:Text",
        "sun_sky (the Hosek-Wilkie sun and sky: the sun columns) or environment (an HDR map: the environment columns)",
    ),
    ("environment", "sc:Text", "base name of the lat-long HDR environment map (environment only)"),
    ("environment_sha256", "sc:Text", "SHA-256 of the map file's bytes (environment only): check a copy against it"),
    (
        "environment_rotation_deg",
        "sc:Float",
        "rotation of the map about the vertical, degrees counter-clockwise (its centre ahead of the camera at 0)",
    ),
    ("environment_scale", "sc:Float", "the map's radiance multiplier (the spec's intensity)"),
)
SCENE_COLUMNS = tuple(c for c, _t, _d in SCENE_COLUMN_DOCS)
#: The scene columns of a material's row: its object (one per material; its lightings agree).
OBJECT_COLUMNS = tuple(c for c in SCENE_COLUMNS if c.startswith("object"))
#: The record's object fields -> their columns.
OBJECT_FIELDS = {
    "kind": "object_kind",
    "sha256": "object_sha256",
    "file_sha256": "object_file_sha256",
    "uv_source": "object_uv_source",
}
#: An environment-lit record's lighting fields -> their columns.
ENVIRONMENT_FIELDS = {
    "file": "environment",
    "sha256": "environment_sha256",
    "rotation_deg": "environment_rotation_deg",
    "scale": "environment_scale",
}
_HEX = frozenset("0123456789abcdef")


def has_scene_columns(description) -> bool:
    """Whether a publication of the dataset described by ``description`` (its ``dataset.json``)
    has the scene columns: where its counts name objects or environment maps, which a build
    writes only for a spec that names other objects or lights (pipeline.dataset.plan)."""
    counts = description.get("counts") if isinstance(description, dict) else None
    return isinstance(counts, dict) and ("objects" in counts or "environments" in counts)


def _object(value) -> dict:
    return value if isinstance(value, dict) else {}


def light_source(record: dict) -> str:
    """``environment`` for an environment-lit record, else ``sun_sky`` (a sun record names no source)."""
    return ENVIRONMENT if _object(record.get("lighting")).get("source") == ENVIRONMENT else SUN_SKY


def scene_values(record: dict) -> dict:
    """The scene columns of a (checked) record: every one of :data:`SCENE_COLUMNS`, null where
    it does not apply (the shaderball's object fields, the sun's environment fields)."""
    obj = record.get("object")
    row = dict.fromkeys(SCENE_COLUMNS)
    row["object"] = obj.get("name") if isinstance(obj, dict) else SHADERBALL
    for name, column in OBJECT_FIELDS.items():
        row[column] = _object(obj).get(name)
    row["light_source"] = light_source(record)
    if row["light_source"] == ENVIRONMENT:
        lighting = record["lighting"]
        for name, column in ENVIRONMENT_FIELDS.items():
            row[column] = lighting.get(name)
    return row


def _digest_problem(where: str, value) -> str | None:
    if isinstance(value, str) and len(value) == 64 and set(value) <= _HEX:
        return None
    return f"{where} is {json_type_name(value)} ({short_json(value)}), not a SHA-256 (64 lowercase hex digits)"


def _finite(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def scene_problem(record: dict) -> str | None:
    """Why a record's scene fields cannot be published as the scene columns say them, or None
    (after pipeline.store.record_fields has checked their JSON types): an object names itself
    and its mesh's SHA-256 (and its file's, if any); an environment light names its map, the
    map's SHA-256, a finite rotation and a finite positive scale; a light source is a known one."""
    obj = record.get("object")
    if obj is not None:
        if not isinstance(obj.get("name"), str) or not obj["name"]:
            return f"object.name is {json_type_name(obj.get('name'))} ({short_json(obj.get('name'))}), not a name"
        for name in ("sha256", "file_sha256") if "file_sha256" in obj else ("sha256",):
            problem = _digest_problem(f"object.{name}", obj.get(name))
            if problem:
                return problem
    lighting = _object(record.get("lighting"))
    source = lighting.get("source", SUN_SKY)
    if source not in LIGHT_SOURCES:
        return f"lighting.source is {short_json(source)}, not one of {', '.join(LIGHT_SOURCES)}"
    if source != ENVIRONMENT:
        return None
    file = lighting.get("file")
    if not isinstance(file, str) or not file:
        return f"lighting.file is {json_type_name(file)} ({short_json(file)}), not a map's name"
    problem = _digest_problem("lighting.sha256", lighting.get("sha256"))
    if problem:
        return problem
    for name, positive in (("rotation_deg", False), ("scale", True)):
        value = lighting.get(name)
        if not _finite(value) or (positive and value <= 0):
            wanted = "a finite number > 0" if positive else "a finite number"
            return f"lighting.{name} is {json_type_name(value)} ({short_json(value)}), not {wanted}"
    return None


@dataclass
class SceneSummary:
    """The objects and environment maps of the published records, with their digests, how
    many samples each lit or carried, and the spans of rotation and scale drawn: what the
    card lists (pipeline.publish.scene_card). One entry per distinct object and map."""

    objects: dict = field(default_factory=dict)  # name -> {kind, sha256, file_sha256, uv_source, samples}
    environments: dict = field(default_factory=dict)  # base name -> {sha256, samples}
    sources: dict = field(default_factory=dict)  # light source -> samples
    rotation_deg: tuple | None = None  # (least, greatest)
    scale: tuple | None = None

    def add(self, record: dict) -> None:
        values = scene_values(record)
        obj = self.objects.setdefault(
            values["object"], {name: values[column] for name, column in OBJECT_FIELDS.items()} | {"samples": 0}
        )
        obj["samples"] += 1
        self.sources[values["light_source"]] = self.sources.get(values["light_source"], 0) + 1
        if values["light_source"] == ENVIRONMENT:
            entry = self.environments.setdefault(values["environment"], {"sha256": values["environment_sha256"]})
            entry["samples"] = entry.get("samples", 0) + 1
            self.rotation_deg = widen(self.rotation_deg, values["environment_rotation_deg"])
            self.scale = widen(self.scale, values["environment_scale"])


def widen(span: tuple | None, value) -> tuple | None:
    """``span`` (least, greatest) widened to hold ``value`` (a number; anything else is left out)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return span
    return (value, value) if span is None else (min(span[0], value), max(span[1], value))
