"""What a publication says about each sample: the member names of a record's files, the
row of ``samples.jsonl`` (the table Croissant's record set reads), and the checks a
manifest record must pass before any of its paths is used.

A row is flat JSON (sorted keys) so that a table reader (pandas, Croissant) reads it
without nested objects; every text column holds letters, so no reader mistakes an id for
a number.
"""

from __future__ import annotations

from dataclasses import dataclass

from pipeline.publish.names import (
    MATERIAL_FIELD,
    MATERIAL_ID,
    MATERIALS,
    PREVIEW_FIELDS,
    RECORD_FIELD,
    ROLE_FIELDS,
    SAMPLE_ID,
    SHARD_ID,
    member_name,
    paired_tar,
)
from pipeline.publish.refusal import Refused
from pipeline.publish.scene_fields import OBJECT_COLUMNS, SCENE_COLUMNS, scene_values
from pipeline.store.layout import Layout

#: The row's columns, in the order the card and Croissant describe them: (column, Croissant
#: data type, meaning). Values of a uniform material are null for an SVBRDF, and the reverse.
COLUMN_DOCS = (
    ("id", "sc:Text", "sample id, MATERIAL_lLIGHT (e.g. m000012_l3); the WebDataset key of its members"),
    ("material_id", "sc:Text", "material id, m + 6 digits; the key of its maps members"),
    ("material_index", "sc:Integer", "index of the material in the plan"),
    ("light_index", "sc:Integer", "index of the lighting among the material's lightings"),
    ("source_shard", "sc:Text", "shard of the source dataset, sNNNNN (its folder shards/sNNNNN)"),
    ("shard", "sc:Text", "the renders tar of PUB holding the sample's record, render and render preview"),
    ("material_shard", "sc:Text", "the materials tar of PUB holding its material's maps (the same number)"),
    ("sun_x", "sc:Float", "unit vector towards the sun, x (world frame, z up)"),
    ("sun_y", "sc:Float", "unit vector towards the sun, y"),
    ("sun_z", "sc:Float", "unit vector towards the sun, z (up)"),
    ("elevation_deg", "sc:Float", "sun elevation above the horizon, degrees (as rendered)"),
    ("azimuth_deg", "sc:Float", "sun azimuth, degrees counter-clockwise from +x seen from above"),
    ("turbidity", "sc:Float", "atmospheric turbidity of the Hosek-Wilkie sky, 1 to 10"),
    ("material_kind", "sc:Text", "uniform (one value per map) or svbrdf (spatially varying)"),
    ("svbrdf_family", "sc:Text", "procedural SVBRDF family (svbrdf only)"),
    ("svbrdf_file", "sc:Text", "imported SVBRDF map file as recorded at build time (imported svbrdf only)"),
    ("diffuse_r", "sc:Float", "uniform diffuse albedo, linear red"),
    ("diffuse_g", "sc:Float", "uniform diffuse albedo, linear green"),
    ("diffuse_b", "sc:Float", "uniform diffuse albedo, linear blue"),
    ("specular_r", "sc:Float", "uniform specular albedo (F0), linear red"),
    ("specular_g", "sc:Float", "uniform specular albedo (F0), linear green"),
    ("specular_b", "sc:Float", "uniform specular albedo (F0), linear blue"),
    ("roughness", "sc:Float", "uniform roughness (GGX alpha = roughness^2)"),
    ("normal_x", "sc:Float", "uniform tangent-space normal, x"),
    ("normal_y", "sc:Float", "uniform tangent-space normal, y"),
    ("normal_z", "sc:Float", "uniform tangent-space normal, z"),
    ("flagged", "sc:Boolean", "the render kept NaN, infinite or negative pixels after every retry"),
    ("seed_material", "sc:Integer", "plan seed of the material's maps (63-bit)"),
    ("seed_light", "sc:Integer", "plan seed of the lighting draw (63-bit)"),
    ("seed_render", "sc:Integer", "mi.render seed of the stored render"),
    ("record", "sc:Text", "tar member: the sample's record (JSON, docs/manifest.md)"),
    ("record_sha256", "sc:Text", "SHA-256 of the record member"),
    ("record_bytes", "sc:Integer", "size of the record member"),
    ("render", "sc:Text", "tar member: the path-traced render (EXR, render.R/G/B float32)"),
    ("render_sha256", "sc:Text", "SHA-256 of the render member"),
    ("render_bytes", "sc:Integer", "size of the render member"),
    ("render_preview", "sc:Text", "tar member: the render tone-mapped, 8-bit sRGB PNG (for people, not data)"),
    ("render_preview_sha256", "sc:Text", "SHA-256 of the render preview member"),
    ("render_preview_bytes", "sc:Integer", "size of the render preview member"),
    ("maps", "sc:Text", "tar member: the material's screen-space maps (EXR), shared by its lightings"),
    ("maps_sha256", "sc:Text", "SHA-256 of the maps member"),
    ("maps_bytes", "sc:Integer", "size of the maps member"),
    ("maps_preview", "sc:Text", "tar member: a strip of the maps (diffuse, specular, roughness, normal), PNG"),
    ("maps_preview_sha256", "sc:Text", "SHA-256 of the maps preview member"),
    ("maps_preview_bytes", "sc:Integer", "size of the maps preview member"),
    ("texture", "sc:Text", "tar member: the material's texture-space maps (EXR), if stored"),
    ("texture_sha256", "sc:Text", "SHA-256 of the texture member"),
    ("texture_bytes", "sc:Integer", "size of the texture member"),
)
COLUMNS = tuple(c for c, _t, _d in COLUMN_DOCS)
#: The columns of a material's row (its ``MATERIAL.json`` member in the materials tar).
MATERIAL_COLUMNS = tuple(
    c
    for c in COLUMNS
    if c in ("material_id", "material_index", "source_shard", "material_shard", "material_kind", "seed_material")
    or c.startswith(("svbrdf_", "diffuse_", "specular_", "roughness", "normal_", "maps", "texture"))
)
#: Preview roles -> the samples table's columns of their SHA-256 and size.
PREVIEW_ROLES = ("render_preview", "maps_preview")


@dataclass(frozen=True)
class FileRef:
    """One EXR file of a record: its role, its path in the source folder, its member name."""

    role: str
    path: str
    member: str
    sha256: str
    bytes: int


def _where(source: str, record) -> str:
    ident = record.get("id") if isinstance(record, dict) else None
    return f"{source} ({ident})" if isinstance(ident, str) else source


def file_refs(record, source: str) -> dict[str, FileRef]:
    """The record's files by role, each path checked to be exactly the layout's, or Refused.

    ``source`` names where the record was read (``dataset/manifest.jsonl line 3``).
    """
    where = _where(source, record)
    if not isinstance(record, dict):
        raise Refused("bad_record", f"{source}: not a JSON object")
    sample, material, shard = record.get("id"), record.get("material_id"), record.get("shard")
    for field, value, pattern in (
        ("id", sample, SAMPLE_ID),
        ("material_id", material, MATERIAL_ID),
        ("shard", shard, SHARD_ID),
    ):
        if not isinstance(value, str) or pattern.match(value) is None:
            raise Refused("bad_record", f"{where}: {field} {value!r} does not fit the layout; refused")
    if not sample.startswith(material + "_l"):
        raise Refused("bad_record", f"{where}: id {sample!r} is not a lighting of material {material!r}")
    expected = {
        "render": Layout.render_rel(shard, sample),
        "maps": Layout.maps_rel(shard, material),
        "texture": Layout.texture_rel(shard, material),
    }
    files = record.get("files")
    if not isinstance(files, list):
        raise Refused("bad_record", f"{where}: files is not a list")
    refs: dict[str, FileRef] = {}
    for entry in files:
        if not isinstance(entry, dict):
            raise Refused("bad_record", f"{where}: a files entry is not an object")
        role, path = entry.get("role"), entry.get("path")
        if not isinstance(role, str) or role not in expected or role in refs:
            raise Refused("bad_record", f"{where}: file role {role!r} is unknown or repeated")
        if path != expected[role]:
            raise Refused(
                "manifest_path",
                f"{where}: {role} file path {path!r} is not the layout's "
                f"{expected[role]!r} (it could point outside the dataset); refused",
            )
        sha, size = entry.get("sha256"), entry.get("bytes")
        if not (isinstance(sha, str) and len(sha) == 64 and all(c in "0123456789abcdef" for c in sha)):
            raise Refused("bad_record", f"{where}: {role} file sha256 {sha!r} is not 64 hex digits")
        if isinstance(size, bool) or not isinstance(size, int) or size < 0:
            raise Refused("bad_record", f"{where}: {role} file bytes {size!r} is not a size")
        key = sample if role == "render" else material
        refs[role] = FileRef(role, path, member_name(key, ROLE_FIELDS[role]), sha, size)
    for role in ("render", "maps"):
        if role not in refs:
            raise Refused("bad_record", f"{where}: no {role} file")
    return refs


def record_member(sample_id: str) -> str:
    return member_name(sample_id, RECORD_FIELD)


def _triple(values, index: int):
    return values[index] if isinstance(values, list) and len(values) == 3 else None


def _object(value) -> dict:
    return value if isinstance(value, dict) else {}


def material_member(material_id: str) -> str:
    return member_name(material_id, MATERIAL_FIELD)


def preview_member(record: dict, role: str) -> str:
    key = record["id"] if role == "render_preview" else record["material_id"]
    return member_name(key, PREVIEW_FIELDS[role])


def sample_row(
    record: dict,
    tar: str,
    record_sha256: str,
    record_bytes: int,
    previews: dict[str, tuple[str, int]],
    scene: bool = False,
) -> dict:
    """The ``samples.jsonl`` row of a (checked) manifest record in the renders tar ``tar``;
    ``previews``: role (render_preview, maps_preview) -> (SHA-256, size) of its PNG member;
    ``scene``: with the scene columns (pipeline.publish.scene_fields.has_scene_columns)."""
    refs = file_refs(record, "manifest")
    lighting = _object(record.get("lighting"))
    direction = lighting.get("direction")
    material = _object(record.get("material"))
    values = _object(material.get("values"))
    seeds = _object(record.get("seeds"))
    texture = refs.get("texture")
    row = {
        "id": record["id"],
        "material_id": record["material_id"],
        "material_index": record.get("material_index"),
        "light_index": record.get("light_index"),
        "source_shard": record["shard"],
        "shard": tar,
        "material_shard": paired_tar(tar, MATERIALS),
        "sun_x": _triple(direction, 0),
        "sun_y": _triple(direction, 1),
        "sun_z": _triple(direction, 2),
        "elevation_deg": lighting.get("elevation_deg"),
        "azimuth_deg": lighting.get("azimuth_deg"),
        "turbidity": lighting.get("turbidity"),
        "material_kind": material.get("kind"),
        "svbrdf_family": material.get("family"),
        "svbrdf_file": material.get("file"),
        "diffuse_r": _triple(values.get("diffuse"), 0),
        "diffuse_g": _triple(values.get("diffuse"), 1),
        "diffuse_b": _triple(values.get("diffuse"), 2),
        "specular_r": _triple(values.get("specular"), 0),
        "specular_g": _triple(values.get("specular"), 1),
        "specular_b": _triple(values.get("specular"), 2),
        "roughness": values.get("roughness"),
        "normal_x": _triple(values.get("normal"), 0),
        "normal_y": _triple(values.get("normal"), 1),
        "normal_z": _triple(values.get("normal"), 2),
        "flagged": bool(_object(record.get("stats")).get("flagged")),
        "seed_material": seeds.get("material"),
        "seed_light": seeds.get("light"),
        "seed_render": seeds.get("render_used"),
        "record": record_member(record["id"]),
        "record_sha256": record_sha256,
        "record_bytes": record_bytes,
        "texture": None,
        "texture_sha256": None,
        "texture_bytes": None,
    }
    for role in ("render", "maps") + (("texture",) if texture else ()):
        ref = refs[role]
        row[role], row[f"{role}_sha256"], row[f"{role}_bytes"] = ref.member, ref.sha256, ref.bytes
    for role in PREVIEW_ROLES:
        sha, size = previews[role]
        row[role], row[f"{role}_sha256"], row[f"{role}_bytes"] = preview_member(record, role), sha, size
    if scene:
        row.update(scene_values(record))
    assert set(row) == set(COLUMNS) | (set(SCENE_COLUMNS) if scene else set())
    return row


def material_row(row: dict) -> dict:
    """The row of a sample's material (its ``MATERIAL.json`` member): the material's columns
    of any of its lightings' ``samples.jsonl`` rows, but for nulls (a column absent is null:
    the card's features type it; a loader that guesses types from the first rows, such as
    ``load_dataset("webdataset")`` without features, then never sees a null-typed column
    meet a value). A publication with the scene columns adds the material's object's."""
    return {column: row[column] for column in MATERIAL_COLUMNS + OBJECT_COLUMNS if row.get(column) is not None}
