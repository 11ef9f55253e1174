"""What the Hugging Face ``datasets`` library loads from a publication: the card's ``configs``
and the ``features`` it declares for each (``dataset_info``), so ``load_dataset(PUB)`` and the
Hub's viewer get typed columns (nulls typed, 63-bit seeds as int64) and ``Image`` columns.

Two configs: ``renders`` (the default: a row per sample from the renders tars) and
``materials`` (a row per material from the materials tars; join on ``__key__`` = the
sample's ``material_id``). ``samples.jsonl`` is no config: ``datasets`` picks one builder for
all configs of a folder (here WebDataset, which would read the table as a tar). The WebDataset loader
names a tar's columns by their member fields (``json``, ``render.exr``, ...) and drops fields
the features leave out; the record is the sample's record file, of which ``RECORD_FEATURES``
declares the fields a trainer needs (the whole record is in ``dataset/manifest.jsonl``); a
publication with the scene columns (pipeline.publish.scene_fields) also declares the record's
``object`` and its environment light's fields, and the material's object columns.

Pure data and text: nothing here imports ``datasets`` (tests load the card with it).
"""

from __future__ import annotations

from pipeline.publish.names import MATERIALS, RENDERS
from pipeline.publish.scene_fields import OBJECT_COLUMNS, SCENE_COLUMN_DOCS
from pipeline.publish.table import COLUMN_DOCS, MATERIAL_COLUMNS
from pipeline.store.layout import SHARDS_DIR

#: Croissant data types -> Hugging Face dtypes.
DTYPES = {"sc:Text": "string", "sc:Integer": "int64", "sc:Float": "float64", "sc:Boolean": "bool"}

F64, I64, TEXT, BOOL = "float64", "int64", "string", "bool"


def vector(dtype: str) -> dict:
    return {"list": dtype}


#: The fields of a sample's record (docs/manifest.md) the ``renders`` config declares.
RECORD_FEATURES = {
    "id": TEXT,
    "material_id": TEXT,
    "material_index": I64,
    "light_index": I64,
    "shard": TEXT,
    "lighting": {
        "elevation_deg": F64,
        "azimuth_deg": F64,
        "turbidity": F64,
        "direction": vector(F64),
    },
    "lighting_vector": vector("float32"),
    "material": {
        "kind": TEXT,
        "family": TEXT,
        "file": TEXT,
        "values": {"diffuse": vector(F64), "specular": vector(F64), "roughness": F64, "normal": vector(F64)},
    },
    "seeds": {"material": I64, "light": I64, "render": I64, "render_used": I64},
    "render": {"integrator": TEXT, "max_depth": I64, "resolution": I64, "spp": I64, "sun": TEXT, "variant": TEXT},
    "effects": {"textured": BOOL, "normal_map": BOOL, "diffuse_lobe": BOOL, "specular_lobe": BOOL},
    "stats": {
        "flagged": BOOL,
        "attempts": I64,
        "nan": I64,
        "inf": I64,
        "negative": I64,
        "min": F64,
        "max": F64,
        "mean": F64,
        "noise_relative": F64,
        "noise_rmse": F64,
    },
}

#: The scene fields of a record (an object's; an environment light's) a publication with the
#: scene columns declares (pipeline.publish.scene_fields): null where a record has none (the
#: shaderball's has no ``object``, a sun's lighting no ``source``).
SCENE_RECORD_FEATURES = {
    "object": {"name": TEXT, "kind": TEXT, "sha256": TEXT, "uv_source": TEXT, "file_sha256": TEXT},
    "lighting": {"source": TEXT, "file": TEXT, "sha256": TEXT, "rotation_deg": F64, "scale": F64},
}

COLUMN_TYPES = {column: DTYPES[data_type] for column, data_type, _ in COLUMN_DOCS + SCENE_COLUMN_DOCS}


def record_features(scene: bool = False) -> dict:
    """The record's features: :data:`RECORD_FEATURES`, with :data:`SCENE_RECORD_FEATURES` where ``scene``."""
    if not scene:
        return RECORD_FEATURES
    features = {**RECORD_FEATURES, "lighting": {**RECORD_FEATURES["lighting"], **SCENE_RECORD_FEATURES["lighting"]}}
    features["object"] = SCENE_RECORD_FEATURES["object"]
    return features


def config_features(texture: bool, scene: bool = False) -> dict[str, dict]:
    """config name -> its features (name -> dtype, ``{"list": dtype}``, a dict of sub-fields,
    or ``"image"``), in the order the loader gives the columns; ``scene``: with the scene
    fields (the record's object and environment light, the material's object columns)."""
    materials = {"__key__": TEXT, "maps.png": "image", "maps.exr": "binary"}
    if texture:
        materials["texture.exr"] = "binary"
    materials["json"] = {c: COLUMN_TYPES[c] for c in MATERIAL_COLUMNS + (OBJECT_COLUMNS if scene else ())}
    materials["__url__"] = TEXT
    return {
        RENDERS: {
            "__key__": TEXT,
            "render.png": "image",
            "render.exr": "binary",
            "json": record_features(scene),
            "__url__": TEXT,
        },
        MATERIALS: materials,
    }


def config_files() -> dict[str, str]:
    return {
        RENDERS: f"{SHARDS_DIR}/{RENDERS}-*.tar",
        MATERIALS: f"{SHARDS_DIR}/{MATERIALS}-*.tar",
    }


def _feature_lines(name: str, feature, indent: int) -> list[str]:
    pad = " " * indent
    lines = [f"{pad}- name: {name}"]
    if isinstance(feature, str):
        return lines + [f"{pad}  dtype: {feature}"]
    if "list" in feature and isinstance(feature["list"], str) and len(feature) == 1:
        return lines + [f"{pad}  list: {feature['list']}"]
    lines.append(f"{pad}  struct:")
    for child, sub in feature.items():
        lines += _feature_lines(child, sub, indent + 2)
    return lines


def yaml_configs(texture: bool, scene: bool = False) -> list[str]:
    """The card's ``configs`` and ``dataset_info`` (YAML lines); ``scene``: :func:`config_features`'."""
    lines = ["configs:"]
    for number, (name, path) in enumerate(config_files().items()):
        lines += [f"- config_name: {name}"]
        if number == 0:
            lines.append("  default: true")
        lines += ["  data_files:", "  - split: train", f"    path: {path}"]
    lines.append("dataset_info:")
    for name, features in config_features(texture, scene).items():
        lines += [f"- config_name: {name}", "  features:"]
        for field, feature in features.items():
            lines += _feature_lines(field, feature, 2)
    return lines
