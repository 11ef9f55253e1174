"""The one place that knows the layout of a published dataset (``PUB``) and the names of
its tar members (docs/publish.md).

    PUB/
      README.md                      dataset card (Hugging Face YAML header)
      croissant.json                 Croissant 1.1 metadata
      publication.json               format version, source dataset, the tar shards
      samples.jsonl                  one row per sample: the table Croissant's record set reads
      preview.png                    contact sheet (pipeline.check.preview)
      SHA256SUMS                     SHA-256 of every other file (``sha256sum -c`` format)
      dataset/spec.toml              the source folder's files, byte for byte
      dataset/dataset.json
      dataset/manifest.jsonl
      dataset/markers.jsonl          every shard's COMPLETE.json, one per line, in shard order
      shards/materials-000000.tar    WebDataset tars (uncompressed USTAR), in pairs: the maps of
      shards/renders-000000.tar        some whole materials, and the renders of their lightings

A materials tar holds, for each of its materials in plan order, ``m000012.json`` (the
material's row, pipeline.publish.table.material_row), ``m000012.maps.exr``,
``m000012.texture.exr`` (if the spec stores them) and ``m000012.maps.png`` (a preview
strip of the maps). The renders tar of the same number holds, for each lighting of those
materials, ``m000012_l0.json`` (the sample's record file), ``m000012_l0.render.exr`` and
``m000012_l0.render.png`` (the render tone-mapped). Every key of a tar has the same fields
(what the Hugging Face WebDataset loader requires); a key (the part before the first dot)
never holds a dot; a material and its lightings are in tars of the same number.
"""

from __future__ import annotations

import re

from pipeline.store.layout import DESCRIPTION_FILE, MANIFEST_FILE, SHARDS_DIR, SPEC_FILE

FORMAT = "shaderball-publish"
FORMAT_VERSION = 2

CARD_FILE = "README.md"
CROISSANT_FILE = "croissant.json"
INDEX_FILE = "publication.json"
SAMPLES_FILE = "samples.jsonl"
PREVIEW_FILE = "preview.png"
SUMS_FILE = "SHA256SUMS"
DATASET_DIR = "dataset"
MARKERS_FILE = "markers.jsonl"

#: The source folder's root files and where they are published.
SOURCE_FILES = {
    SPEC_FILE: f"{DATASET_DIR}/{SPEC_FILE}",
    DESCRIPTION_FILE: f"{DATASET_DIR}/{DESCRIPTION_FILE}",
    MANIFEST_FILE: f"{DATASET_DIR}/{MANIFEST_FILE}",
}
MARKERS_REL = f"{DATASET_DIR}/{MARKERS_FILE}"

#: Files of PUB other than the tar shards, in the order SHA256SUMS lists them (sorted).
PLAIN_FILES = tuple(
    sorted([CARD_FILE, CROISSANT_FILE, INDEX_FILE, SAMPLES_FILE, PREVIEW_FILE, MARKERS_REL, *SOURCE_FILES.values()])
)
#: Files that may be absent (a publication written without a contact sheet).
OPTIONAL_FILES = (PREVIEW_FILE,)

#: The two kinds of tar: a material's files, and a lighting's. Every name pattern ends with
#: ``\Z``, not ``$`` (which also matches before a final newline), and is ASCII-only (``\d``
#: would otherwise match any Unicode digit): a name is accepted only as the layout spells it.
MATERIALS, RENDERS = "materials", "renders"
TAR_KINDS = (MATERIALS, RENDERS)
TAR_NAME = re.compile(r"^shards/(materials|renders)-(\d{6})\.tar\Z", re.ASCII)
SAMPLE_ID = re.compile(r"^m\d{6}_l\d{1,3}\Z", re.ASCII)
MATERIAL_ID = re.compile(r"^m\d{6}\Z", re.ASCII)
SHARD_ID = re.compile(r"^s\d{5}\Z", re.ASCII)
#: A member name: a key without a dot, then its field.
MEMBER_NAME = re.compile(
    r"^(m\d{6})\.(json|maps\.exr|texture\.exr|maps\.png)\Z|^(m\d{6}_l\d{1,3})\.(json|render\.exr|render\.png)\Z",
    re.ASCII,
)

#: Record roles (docs/manifest.md) -> member field.
ROLE_FIELDS = {"render": "render.exr", "maps": "maps.exr", "texture": "texture.exr"}
RECORD_FIELD = "json"
MATERIAL_FIELD = "json"
#: Previews (pipeline.publish.previews): role -> member field.
PREVIEW_FIELDS = {"render_preview": "render.png", "maps_preview": "maps.png"}


def tar_rel(index: int, kind: str = RENDERS) -> str:
    return f"{SHARDS_DIR}/{kind}-{index:06d}.tar"


def paired_tar(rel: str, kind: str) -> str:
    """The tar of kind ``kind`` with the number of the tar ``rel`` (a TAR_NAME)."""
    return tar_rel(int(TAR_NAME.match(rel).group(2)), kind)


def member_name(key: str, field: str) -> str:
    return f"{key}.{field}"


def allowed_file(rel: str) -> bool:
    """Whether ``rel`` (relative to PUB, forward slashes) is a file a publication may hold."""
    return rel in PLAIN_FILES or TAR_NAME.match(rel) is not None
