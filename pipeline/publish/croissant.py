"""``croissant.json``: Croissant 1.1 metadata of a publication (http://mlcommons.org/croissant/1.1).

Every file of PUB but the card and SHA256SUMS is a FileObject with its SHA-256; the EXR,
PNG and JSON members of the tars are FileSets ``containedIn`` the tars of their kind
(materials, renders). Croissant's reader cannot
decode EXR, and its extractor unpacks archives with ``extractall``; so the record set
``samples`` reads only ``samples.jsonl`` (one row per sample, naming its members, their
checksums and the tar that holds them), never the tars.
"""

from __future__ import annotations

from pipeline.publish.names import (
    INDEX_FILE,
    MARKERS_REL,
    MATERIALS,
    PREVIEW_FILE,
    RENDERS,
    SAMPLES_FILE,
    SOURCE_FILES,
)
from pipeline.publish.publication_facts import CITATION, LICENSES, PublicationFacts
from pipeline.publish.scene_card import GEOMETRY_DOCS, geometry_layers, has_scene
from pipeline.publish.scene_fields import SCENE_COLUMN_DOCS
from pipeline.publish.table import COLUMN_DOCS
from pipeline.store.exr import LAYER_CHANNELS

CONFORMS_TO = "http://mlcommons.org/croissant/1.1"
RECORD_SET = "samples"

#: The JSON-LD context of Croissant 1.1 (as its reference datasets write it).
CONTEXT = {
    "@language": "en",
    "@vocab": "https://schema.org/",
    "arrayShape": "cr:arrayShape",
    "citeAs": "cr:citeAs",
    "column": "cr:column",
    "conformsTo": "dct:conformsTo",
    "containedIn": "cr:containedIn",
    "cr": "http://mlcommons.org/croissant/",
    "rai": "http://mlcommons.org/croissant/RAI/",
    "data": {"@id": "cr:data", "@type": "@json"},
    "dataType": {"@id": "cr:dataType", "@type": "@vocab"},
    "dct": "http://purl.org/dc/terms/",
    "description": {"@container": "@language"},
    "equivalentProperty": "cr:equivalentProperty",
    "examples": {"@id": "cr:examples", "@type": "@json"},
    "extract": "cr:extract",
    "field": "cr:field",
    "fileProperty": "cr:fileProperty",
    "fileObject": "cr:fileObject",
    "fileSet": "cr:fileSet",
    "format": "cr:format",
    "includes": "cr:includes",
    "isArray": "cr:isArray",
    "isLiveDataset": "cr:isLiveDataset",
    "jsonPath": "cr:jsonPath",
    "key": "cr:key",
    "md5": "cr:md5",
    "name": {"@container": "@language"},
    "parentField": "cr:parentField",
    "path": "cr:path",
    "recordSet": "cr:recordSet",
    "references": "cr:references",
    "regex": "cr:regex",
    "repeated": "cr:repeated",
    "replace": "cr:replace",
    "samplingRate": "cr:samplingRate",
    "sc": "https://schema.org/",
    "separator": "cr:separator",
    "source": "cr:source",
    "subField": "cr:subField",
    "transform": "cr:transform",
}

#: Columns read as one field with sub-fields (a vector).
VECTORS = {
    "sun_direction": (("sun_x", "x"), ("sun_y", "y"), ("sun_z", "z")),
    "diffuse": (("diffuse_r", "r"), ("diffuse_g", "g"), ("diffuse_b", "b")),
    "specular": (("specular_r", "r"), ("specular_g", "g"), ("specular_b", "b")),
    "normal": (("normal_x", "x"), ("normal_y", "y"), ("normal_z", "z")),
}
VECTOR_DOCS = {
    "sun_direction": "unit vector towards the sun (world frame, z up)",
    "diffuse": "uniform diffuse albedo, linear Rec.709 (null for an SVBRDF)",
    "specular": "uniform specular albedo F0, linear Rec.709 (null for an SVBRDF)",
    "normal": "uniform tangent-space normal (null for an SVBRDF)",
}

MEMBER_SETS = (
    ("render-exr", RENDERS, "*.render.exr", "image/x-exr", "renders: render.R/G/B, linear HDR float32"),
    ("render-png", RENDERS, "*.render.png", "image/png", "render previews: tone-mapped, 8-bit sRGB (not data)"),
    ("record-json", RENDERS, "*.json", "application/json", "per-sample records (docs/manifest.md)"),
    (
        "maps-exr",
        MATERIALS,
        "*.maps.exr",
        "image/x-exr",
        "screen-space maps of a material: diffuse, specular, roughness, normal, mask",
    ),
    ("texture-exr", MATERIALS, "*.texture.exr", "image/x-exr", "texture-space (UV) maps of a material"),
    (
        "maps-png",
        MATERIALS,
        "*.maps.png",
        "image/png",
        "map previews: diffuse, specular, roughness, normal side by side, 8-bit (not data)",
    ),
    (
        "material-json",
        MATERIALS,
        "*.json",
        "application/json",
        "per-material rows: the samples table's material columns",
    ),
)

FORMATS = {
    ".tar": "application/x-tar",
    ".jsonl": "application/jsonlines",
    ".json": "application/json",
    ".toml": "application/toml",
    ".png": "image/png",
}


def _file_object(rel: str, facts: PublicationFacts, description: str) -> dict:
    suffix = rel[rel.rfind(".") :]
    return {
        "@type": "cr:FileObject",
        "@id": rel,
        "name": rel,
        "description": description,
        "contentUrl": rel,
        "contentSize": f"{facts.sizes[rel]} B",
        "encodingFormat": FORMATS[suffix],
        "sha256": facts.files[rel],
    }


def _field(column: str, data_type: str, description: str, field_id: str) -> dict:
    return {
        "@type": "cr:Field",
        "@id": field_id,
        "name": field_id.rsplit("/", 1)[-1],
        "description": description,
        "dataType": data_type,
        "source": {"fileObject": {"@id": SAMPLES_FILE}, "extract": {"column": column}},
    }


def record_set_fields(scene: bool = False, geometry: tuple[str, ...] = ()) -> list[dict]:
    """The record set's fields: a column each (vectors as one field with sub-fields); ``scene``:
    and the scene columns (pipeline.publish.scene_fields); ``geometry``: and a field per geometry
    layer the maps member holds (:func:`geometry_fields`)."""
    docs = {c: (t, d) for c, t, d in COLUMN_DOCS}
    in_vector = {column: name for name, parts in VECTORS.items() for column, _ in parts}
    fields, done = [], set()
    for column, data_type, description in COLUMN_DOCS:
        vector = in_vector.get(column)
        if vector is None:
            fields.append(_field(column, data_type, description, f"{RECORD_SET}/{column}"))
        elif vector not in done:
            done.add(vector)
            fields.append(
                {
                    "@type": "cr:Field",
                    "@id": f"{RECORD_SET}/{vector}",
                    "name": vector,
                    "description": VECTOR_DOCS[vector],
                    "subField": [
                        _field(c, docs[c][0], docs[c][1], f"{RECORD_SET}/{vector}/{axis}")
                        for c, axis in VECTORS[vector]
                    ],
                }
            )
    if scene:
        fields += [_field(c, t, d, f"{RECORD_SET}/{c}") for c, t, d in SCENE_COLUMN_DOCS]
    return fields + geometry_fields(geometry)


def geometry_fields(layers: tuple[str, ...]) -> list[dict]:
    """A field per geometry layer the maps members hold, read from the ``maps`` column: the
    member that holds the layer (Croissant cannot decode EXR, so the field names where the
    layer is, its channels and meaning; the record set never opens a tar)."""
    return [
        _field(
            "maps",
            "sc:Text",
            f"tar member holding layer {layer} (EXR channels {', '.join(f'{layer}.{c}' for c in LAYER_CHANNELS[layer])}"
            f", float32, 0 outside the mask): {GEOMETRY_DOCS[layer]}",
            f"{RECORD_SET}/{layer}",
        )
        for layer in layers
    ]


def croissant_metadata(facts: PublicationFacts) -> dict:
    counts = facts.description.get("counts") or {}
    resolution = facts.spec.render.resolution
    distribution = [
        _file_object(
            t.path,
            facts,
            f"tar shard (WebDataset convention), {t.kind}: "
            + (f"materials {t.first} to {t.last}" if t.kind == MATERIALS else f"samples {t.first} to {t.last}")
            + f", {t.members} members",
        )
        for t in facts.tars
    ]
    distribution.append(
        _file_object(SAMPLES_FILE, facts, "one row per sample: lighting, material, members and their SHA-256")
    )
    for rel, what in (
        (SOURCE_FILES["spec.toml"], "the spec the dataset was built from"),
        (SOURCE_FILES["dataset.json"], "the source dataset's description: versions, counts"),
        (SOURCE_FILES["manifest.jsonl"], "every sample's full record (docs/manifest.md)"),
        (MARKERS_REL, "the source shards' completion markers"),
        (INDEX_FILE, "publication format, source dataset, tar shards"),
    ):
        distribution.append(_file_object(rel, facts, what))
    if facts.has_preview:
        distribution.append(_file_object(PREVIEW_FILE, facts, "contact sheet: renders beside their maps"))
    for set_id, kind, pattern, encoding, what in MEMBER_SETS:
        if set_id == "texture-exr" and not facts.summary.has_texture:
            continue
        if set_id == "maps-exr" and geometry_layers(facts.spec):
            what += ", and the object's geometry: " + ", ".join(geometry_layers(facts.spec)) + " (float32)"
        distribution.append(
            {
                "@type": "cr:FileSet",
                "@id": set_id,
                "name": set_id,
                "description": what,
                "containedIn": [{"@id": t.path} for t in facts.tars if t.kind == kind],
                "encodingFormat": encoding,
                "includes": pattern,
            }
        )
    metadata = {
        "@context": CONTEXT,
        "@type": "sc:Dataset",
        "name": facts.name,
        "description": _scene_description(facts)
        if has_scene(facts)
        else (
            f"{facts.summary.samples} path-traced renders ({resolution}x{resolution}, {facts.spec.render.spp} spp, "
            f"Mitsuba 3) of a shaderball with {counts.get('materials', facts.materials)} materials "
            f"({counts.get('uniform', '?')} uniform, {counts.get('svbrdf', '?')} spatially varying) under a "
            "Hosek-Wilkie sun and sky, each with its material's screen-space maps (diffuse, specular, roughness, "
            "normal) and lighting vector (sun direction, turbidity): the data of 'A Flexible Neural Renderer "
            "for Material Visualization' (SIGGRAPH Asia 2019), made with shaderball."
        ),
        "conformsTo": CONFORMS_TO,
        "license": LICENSES[facts.license_id],
        "version": _semver(facts.description.get("version")),
        "citeAs": CITATION,
        "keywords": ["rendering", "path tracing", "materials", "SVBRDF", "neural rendering", "HDR", "EXR"],
        "distribution": distribution,
        "recordSet": [
            {
                "@type": "cr:RecordSet",
                "@id": RECORD_SET,
                "name": RECORD_SET,
                "description": "one record per sample (render); its EXR files are the tar members it "
                "names, in the tar it names",
                "key": {"@id": f"{RECORD_SET}/id"},
                "field": record_set_fields(has_scene(facts), geometry_layers(facts.spec)),
            }
        ],
    }
    if facts.url:
        metadata["url"] = facts.url
    return metadata


def _scene_description(facts: PublicationFacts) -> str:
    """The dataset's description where its samples are on other objects or under environment maps."""
    counts = facts.description.get("counts") or {}
    resolution = facts.spec.render.resolution
    objects = ", ".join(facts.summary.scene.objects)
    light = (
        "HDR environment maps (named and digested per sample; not included)"
        if facts.summary.scene.environments
        else "a Hosek-Wilkie sun and sky"
    )
    return (
        f"{facts.summary.samples} path-traced renders ({resolution}x{resolution}, {facts.spec.render.spp} spp, "
        f"Mitsuba 3) of {counts.get('materials', facts.materials)} materials on objects ({objects}) under {light}, "
        "each with its material's screen-space maps, the object's geometry layers where stored and its lighting "
        "vector; made with shaderball after 'A Flexible Neural Renderer for Material Visualization' (SIGGRAPH "
        "Asia 2019). Meshes and maps travel by SHA-256 (columns object_sha256, environment_sha256), not as files."
    )


def _semver(version) -> str:
    """Croissant wants MAJOR.MINOR.PATCH; a spec's dataset.version "1" becomes "1.0.0"."""
    text = str(version or "0")
    parts = text.split(".")
    if all(p.isdigit() for p in parts) and len(parts) <= 3:
        return ".".join(str(int(p)) for p in parts + ["0"] * (3 - len(parts)))
    return text
