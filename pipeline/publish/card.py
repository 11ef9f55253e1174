"""``README.md`` of a publication: a dataset card with the YAML header the Hugging Face Hub
reads, and what a reader needs: what a sample is, how it was made, the paper's citation,
a contact sheet, and how to load it (this tool, webdataset, plain tarfile + OpenEXR).

The card is a pure function of the dataset and the publication's files: publishing the
same folder twice writes the same card.
"""

from __future__ import annotations

import statistics

from pipeline.dataset.spec_file import spec_to_toml
from pipeline.publish import scene_card
from pipeline.publish.hub import yaml_configs
from pipeline.publish.names import (
    CROISSANT_FILE,
    INDEX_FILE,
    MARKERS_REL,
    PREVIEW_FILE,
    SAMPLES_FILE,
    SOURCE_FILES,
    SUMS_FILE,
)
from pipeline.publish.previews import preview_factor
from pipeline.publish.publication_facts import CITATION, PublicationFacts
from pipeline.publish.table import COLUMN_DOCS
from pipeline.store.exr import LAYER_CHANNELS
from pipeline.store.exrheader import ExrBounds
from pipeline.store.records import dumps

EFFECTS = (
    ("textured", "textures (every map holds one value: constants instead)"),
    ("normal_map", "the normal map (every normal is (0, 0, 1))"),
    ("diffuse_lobe", "the diffuse lobe (d (1 - s) = 0 everywhere)"),
    ("specular_lobe", "the specular lobe"),
)

SIZE_CATEGORIES = (
    (1_000, "n<1K"),
    (10_000, "1K<n<10K"),
    (100_000, "10K<n<100K"),
    (1_000_000, "100K<n<1M"),
    (10_000_000, "1M<n<10M"),
)

LOAD_WITH_SHADERBALL = """import sys

from pipeline.errors import ShaderballError
from pipeline.publish import iter_samples
from pipeline.store.exr import read_exr

root = "."  # the folder holding this card
n = 0
try:
    for sample in iter_samples(root):  # checks every SHA-256 and member as it streams
        record = sample["record"]  # the manifest record (docs/manifest.md)
        render = read_exr(sample["files"]["render"]).layers["render"]  # (H, W, 3) float32
        maps = read_exr(sample["files"]["maps"]).layers  # diffuse, specular, roughness, normal, mask
        n += 1
except ShaderballError as exc:  # a file that is not what the publication says: one line, no traceback
    print(f"error: {exc}", file=sys.stderr)
    sys.exit(2)
"""

#: Where a recipe's EXR check goes (:func:`exr_check`, filled in from the published spec).
CHECK_HERE = "# EXR_CHECK\n"

#: The check each recipe runs on an EXR member before OpenEXR decodes it: its header read in
#: Python and refused unless it is what the publication's spec allows (``{members}``: the
#: channels and side of each member). OpenEXR would decode whatever a header says: a 2 MB
#: render can declare 20000 x 20000 pixels, or list its channels twice (OpenEXR merges the
#: lists), or hide an attribute inside another of the wrong size.
EXR_CHECK = '''#: What this publication's spec allows each EXR member: its channels, its side in pixels, and
#: the most bytes it can hold (header, chunk offsets, pixels); any other member: OTHER_MEMBER_BYTES.
EXR_MEMBERS = {members}
OTHER_MEMBER_BYTES = {other_bytes}
#: The attributes its EXR files hold: type, and size where the type fixes it.
EXR_ATTRIBUTES = {{
    b"channels": (b"chlist", None), b"compression": (b"compression", 1), b"dataWindow": (b"box2i", 16),
    b"displayWindow": (b"box2i", 16), b"lineOrder": (b"lineOrder", 1), b"pixelAspectRatio": (b"float", 4),
    b"screenWindowCenter": (b"v2f", 8), b"screenWindowWidth": (b"float", 4), b"type": (b"string", None),
    b"chromaticities": (b"chromaticities", 32), b"shaderball": (b"string", None),
}}


def refuse(message):
    """End this script with one line on stderr and exit status 2, not a traceback."""
    print(f"error: {{message}}; refused, nothing of it decoded", file=sys.stderr)
    sys.exit(2)


def checked_exr(data, field, key="a sample"):
    """``data``, an EXR member's bytes (``field``: "render.exr" or "maps.exr"; ``key``: its sample's
    or material's key), once its header says what the spec allows: each attribute once, of its
    type and size; the spec's window; the member's channels. Anything else is refused
    (:func:`refuse`) before OpenEXR decodes a pixel."""
    names, side, most = EXR_MEMBERS[field]
    if len(data) > most:
        refuse(f"{{key}} {{field}}: {{len(data)}} bytes, more than an EXR of the spec holds ({{most}})")
    if data[:8] != b"v/1\\x01\\x02\\x00\\x00\\x00":  # EXR magic, version 2: single-part scanline
        refuse(f"{{key}} {{field}}: not a single-part scanline EXR")
    header, at = {{}}, 8
    while data[at : at + 1] != b"\\x00":
        name, kind, _ = data[at : at + 64].split(b"\\x00", 2)
        start = at + len(name) + len(kind) + 6
        size = int.from_bytes(data[start - 4 : start], "little", signed=True)
        at = start + max(size, 0)
        want, fixed = EXR_ATTRIBUTES.get(name, (None, None))
        if name in header or kind != want or size < 0 or size != (fixed or size) or at > len(data):
            refuse(f"{{key}} {{field}}: EXR attribute {{name[:32]!r}} is repeated, unknown or malformed")
        header[name] = data[start:at]
    channels, rest = [], header.get(b"channels", b"")
    while rest[:1] not in (b"", b"\\x00"):
        name, rest = rest.split(b"\\x00", 1)
        channels, rest = channels + [name.decode("latin-1")], rest[16:]
    window = struct.pack("<4i", 0, 0, side - 1, side - 1)
    if sorted(channels) != sorted(names) or header.get(b"dataWindow") != window:
        refuse(f"{{key}} {{field}}: its EXR header says other channels or another size than {{side}} x {{side}}")
    if header.get(b"type", b"scanlineimage") != b"scanlineimage":
        refuse(f"{{key}} {{field}}: not a scanline image")
    return data
'''

LOAD_WITH_DATASETS = """import io
import os
import struct
import sys

import datasets
import OpenEXR

root = os.path.abspath(".")  # the folder holding this card (or the Hub's repository id)
# EXR_CHECK


renders = datasets.load_dataset(root, "renders", split="train")  # the default config
materials = datasets.load_dataset(root, "materials", split="train")
row_of_material = {key: i for i, key in enumerate(materials["__key__"])}
n = 0
for row in renders:  # __key__, render.png (a PIL image), render.exr (bytes), json (the record), __url__
    record = row["json"]  # typed: seeds int64, lighting_vector float32, nulls typed
    material = materials[row_of_material[record["material_id"]]]  # __key__, maps.png, maps.exr, json, ...
    render_exr = checked_exr(row["render.exr"], "render.exr", row["__key__"])
    render = OpenEXR.File(io.BytesIO(render_exr)).channels()["render"].pixels
    maps_exr = OpenEXR.File(io.BytesIO(checked_exr(material["maps.exr"], "maps.exr", material["__key__"])))
    maps = {name: c.pixels for name, c in maps_exr.channels().items()}  # (H, W, 3) "diffuse", "mask.Y", ...
    n += 1
"""

#: The two lines the card shows for turning a row's EXR bytes into float arrays (after the
#: recipes' ``checked_exr``).
EXR_TWO_LINES = """import io, OpenEXR
layers = {name: c.pixels for name, c in OpenEXR.File(io.BytesIO(checked_exr(row["render.exr"], "render.exr"))).channels().items()}
"""

LOAD_WITH_WEBDATASET = '''import io
import json
import struct
import sys

import OpenEXR
import webdataset as wds

root = "."  # the folder holding this card
with open(f"{root}/publication.json") as fh:
    shards = [f"{root}/{shard['path']}" for shard in json.load(fh)["shards"] if shard["kind"] == "renders"]
# EXR_CHECK


def layers(data, field, key):
    exr = OpenEXR.File(io.BytesIO(checked_exr(data, field, key)), separate_channels=True)
    return {name: channel.pixels for name, channel in exr.channels().items()}


def attach_maps(samples):
    """Add to each sample its material's files, read from the materials tar of the same number
    (materials come in the order of their lightings)."""
    url = None
    for sample in samples:
        if sample["__url__"] != url:
            url = sample["__url__"]
            materials = iter(wds.DataPipeline(wds.SimpleShardList([url.replace("/renders-", "/materials-")]),
                                              wds.tarfile_to_samples()))
            material = {"__key__": None}
        while material["__key__"] != sample["__key__"].split("_l")[0]:
            material = next(materials)
        yield {**sample, "maps.exr": material["maps.exr"], "material.json": material["json"]}


dataset = wds.DataPipeline(wds.SimpleShardList(shards), wds.tarfile_to_samples(), attach_maps)
n = 0
for sample in dataset:  # shuffle shards before tarfile_to_samples, samples after attach_maps
    record = json.loads(sample["json"])
    render = layers(sample["render.exr"], "render.exr", sample["__key__"])  # {"render.R": (H, W) float32, ...}
    maps = layers(sample["maps.exr"], "maps.exr", sample["__key__"])  # {"diffuse.R": ..., "mask.Y": ...}
    n += 1
'''

LOAD_WITH_TARFILE = """import io
import json
import struct
import sys
import tarfile

import OpenEXR

root = "."  # the folder holding this card
# EXR_CHECK


def layers(data, field, key):
    exr = OpenEXR.File(io.BytesIO(checked_exr(data, field, key)), separate_channels=True)
    return {name: channel.pixels for name, channel in exr.channels().items()}


def members(path):
    with tarfile.open(f"{root}/{path}", mode="r:") as tar:  # stream members; never extractall
        for member in tar:
            if not member.isfile():
                refuse(f"{path}: {member.name} is not a regular file")
            key, field = member.name.split(".", 1)
            most = EXR_MEMBERS[field][2] if field in EXR_MEMBERS else OTHER_MEMBER_BYTES
            if member.size > most:  # refused before a byte of it is read
                refuse(f"{key} {field}: {member.size} bytes, more than such a member holds ({most})")
            yield key, field, tar.extractfile(member).read()


with open(f"{root}/publication.json") as fh:
    shards = [shard["path"] for shard in json.load(fh)["shards"] if shard["kind"] == "renders"]
n = 0
for path in shards:
    materials = members(path.replace("/renders-", "/materials-"))  # the same materials, in order
    files, maps = {}, {"key": None}
    for key, field, data in members(path):
        files[field] = data
        if field == "render.png":  # a sample's last member: record, render, preview
            while maps["key"] != key.split("_l")[0]:  # read on to its material's files
                maps = {"key": None}
                for material, kind, blob in materials:
                    maps["key"], maps[kind] = material, blob
                    if kind == "maps.png":  # a material's last member
                        break
            record = json.loads(files["json"])
            render = layers(files["render.exr"], "render.exr", key)
            maps_layers = layers(maps["maps.exr"], "maps.exr", maps["key"])
            n += 1
maps = maps_layers
"""


#: The most bytes a recipe reads of a member that is not an EXR (a record's JSON, a preview PNG):
#: a 4096 px 8-bit RGB PNG stored uncompressed is ~50 MB.
OTHER_MEMBER_BYTES = 64 << 20


def exr_check(spec) -> str:
    """The recipes' :data:`EXR_CHECK` for a publication of ``spec``: each EXR member's channels
    (the render's; the maps' ``storage.layers``) and side (``render.resolution``)."""
    side = spec.render.resolution
    roles = {"render.exr": ("render",), "maps.exr": spec.storage.layers}
    lines = ["{"]
    for field, layers in roles.items():
        names = [f"{layer}.{suffix}" for layer in layers for suffix in LAYER_CHANNELS[layer]]
        most = ExrBounds(shape=(side, side), channels=len(names)).file_bytes
        lines.append(f"    {field!r}: ({names!r}, {side}, {most}),".replace("'", '"'))
    return EXR_CHECK.format(members="\n".join(lines + ["}"]), other_bytes=OTHER_MEMBER_BYTES)


def recipe(template: str, spec) -> str:
    """A loading recipe with the EXR check of a publication of ``spec`` in it."""
    return template.replace(CHECK_HERE, "\n" + exr_check(spec))


def size_category(count: int) -> str:
    for bound, name in SIZE_CATEGORIES:
        if count < bound:
            return name
    return "n>10M"


def yaml_header(facts: PublicationFacts) -> list[str]:
    return [
        "---",
        f"license: {facts.license_id}",
        f"pretty_name: {dumps(f'shaderball {facts.name}')}",
        "size_categories:",
        f"- {size_category(facts.summary.samples)}",
        "task_categories:",
        "- image-to-image",
        "tags:",
        *(
            f"- {tag}"
            for tag in (
                "rendering",
                "path-tracing",
                "materials",
                "svbrdf",
                "shaderball",
                "hdr",
                "exr",
                "webdataset",
                "croissant",
                "mitsuba",
            )
        ),
        *yaml_configs(facts.spec.storage.texture_maps, scene_card.has_scene(facts)),
        "---",
    ]


def _range(span: tuple | None) -> str:
    """``least to greatest`` of a :class:`RecordSummary` span, or ``none``."""
    return f"{span[0]:.3g} to {span[1]:.3g}" if span is not None else "none"


def _mb(n: int) -> str:
    return f"{n / 1e6:.2f} MB" if n >= 100_000 else f"{n / 1e3:.1f} KB"


def sample_section(facts: PublicationFacts) -> list[str]:
    spec = facts.spec
    res, tex = spec.render.resolution, spec.materials.texture_resolution
    maps_type = "half" if spec.storage.maps_half else "float32"
    texture = spec.storage.texture_maps
    preview = res // preview_factor(res)
    lines = [
        "## What a sample is",
        "",
        "One sample pairs a material's four screen-space maps and a lighting vector with a path-traced render "
        f"of {scene_card.subject(facts)} (the paper's input and target). Its files are members of uncompressed "
        "tars, named `KEY.FIELD` (the WebDataset convention; a key never holds a dot), in pairs: "
        "`shards/materials-N.tar` holds whole materials, `shards/renders-N.tar` (the same N) their lightings. "
        "Every key of a tar has the same fields, so the Hub's WebDataset loader reads each kind as a config "
        "(`renders`, the default, "
        "and `materials`; join a render to its maps by `material_id` = the material's `__key__`):",
        "",
        "| tar | member | what |",
        "|---|---|---|",
        "| renders | `m000012_l3.json` | the sample's record: lighting (sun elevation, azimuth, direction, "
        "turbidity, low-sun policy), the network's lighting vector, material, seeds, render settings, "
        "statistics, its files with SHA-256 (docs/manifest.md of shaderball) |",
        f"| renders | `m000012_l3.render.exr` | the render: layers `render.R/G/B`, {res}x{res}, float32, linear "
        "Rec.709, physical radiance (a direct view of the sun is about 2e4) |",
        f"| renders | `m000012_l3.render.png` | its preview, {preview}x{preview}: tone-mapped (exposure from the "
        "ball's pixels, Reinhard, sRGB), 8-bit; for people and the viewer, not for training |",
        "| materials | `m000012.json` | the material's row: the material columns of the table below |",
        f"| materials | `m000012.maps.exr` | the material's screen-space maps, what the renderer saw: "
        f"`diffuse.R/G/B`, `specular.R/G/B`, `roughness.Y`, `normal.X/Y/Z` (tangent space) in {maps_type}, "
        f"`mask.Y` (1 where a pixel sees the material) in float32{scene_card.geometry_text(spec)}; {res}x{res} |",
    ]
    if texture:
        lines.append(
            f"| materials | `m000012.texture.exr` | the material's maps in texture (UV) space, {tex}x{tex} "
            "(1x1 for a uniform material) |"
        )
    lines += [
        f"| materials | `m000012.maps.png` | a preview strip, {4 * preview}x{preview}: diffuse and specular "
        "(sRGB-encoded), roughness (grey), normal ((n + 1) / 2) |",
        "",
        "A material's maps are identical under all its lightings, so they are stored **once per material**. "
        "`samples.jsonl` lists every sample with its tars, members and their SHA-256, and the columns below "
        "(Croissant's record set reads it):",
        "",
        "| column | type | meaning |",
        "|---|---|---|",
        *(f"| `{c}` | {t.split(':')[1]} | {d} |" for c, t, d in COLUMN_DOCS),
        *scene_card.column_lines(facts),
        "",
        scene_card.lighting_vector_text(facts),
        "",
    ]
    return lines


def made_section(facts: PublicationFacts) -> list[str]:
    spec, description, summary = facts.spec, facts.description, facts.summary
    counts = description.get("counts") or {}
    libraries = description.get("libraries") or {}
    changed, flagged, noise = summary.policy_changed, summary.flagged, summary.noise
    families = counts.get("svbrdf_sources") or {}
    left_out = []
    for key, what in EFFECTS:
        left_out.append(f"| {what} | {summary.effects_off.get(key, 0)} of {summary.samples} |")
    lines = [
        "## How it was made",
        "",
        f"Built by `shaderball build` (shaderball {description.get('shaderball', '?')}) from the spec "
        f"`{SOURCE_FILES['spec.toml']}` (below; SHA-256 of its canonical form "
        f"`{description.get('spec_digest', '?')}`), rendered with Mitsuba {libraries.get('mitsuba', '?')} "
        f"(drjit {libraries.get('drjit', '?')}, variant `{description.get('variant', '?')}`). Every random draw "
        f"derives from the spec seed {spec.dataset.seed} and the sample's ids; each record holds its seeds "
        "(`seeds.material`, `seeds.light`, `seeds.render_used`), so the same spec, versions and machine "
        "rebuild the same bytes.",
        "",
        f"- **Counts**: {counts.get('materials', facts.materials)} materials x "
        f"{spec.dataset.lights_per_material} lightings = {summary.samples} renders in {counts.get('shards', '?')} "
        f"source shards; {counts.get('uniform', '?')} uniform, {counts.get('svbrdf', '?')} spatially varying"
        + (" (" + ", ".join(f"{k} {v}" for k, v in sorted(families.items())) + ")" if families else "")
        + ".",
        f"- **Renders**: {spec.render.resolution}x{spec.render.resolution}, {spec.render.spp} spp, "
        f"`{spec.render.integrator}` integrator, max depth {spec.render.max_depth}, box filter, sun mode "
        f"`{spec.lighting.sun}`; mean relative noise (standard error / mean over the ball) "
        + (f"{statistics.fmean(noise):.3f}" if noise else "unknown")
        + ".",
        *scene_card.made_lines(facts),
        *scene_card.sun_lines(
            facts,
            f"- **Lighting**: sun scheme `{spec.lighting.scheme}`, elevation {spec.lighting.elevation_deg[0]:g} to "
            f"{spec.lighting.elevation_deg[1]:g} deg, azimuth {spec.lighting.azimuth_deg[0]:g} to "
            f"{spec.lighting.azimuth_deg[1]:g} deg, turbidity {spec.lighting.turbidity[0]:g} to "
            f"{spec.lighting.turbidity[1]:g} (one per {spec.lighting.turbidity_per}). Rendered: elevation "
            f"{_range(summary.elevation)} deg, turbidity "
            f"{_range(summary.turbidity)}; the low-sun policy raised {changed} sun(s).",
        ),
        f"- **Materials**: Cook-Torrance (GGX) as in Deschaintre et al. 2018; uniform materials drawn from "
        f"roughness {spec.materials.roughness[0]:g} to {spec.materials.roughness[1]:g}, metal probability "
        f"{spec.materials.metal_probability:g}, flat-normal probability {spec.materials.flat_normal_probability:g} "
        f"(every range in the spec below); SVBRDFs from the procedural families "
        f"{', '.join(spec.materials.svbrdf_families) or 'none'}"
        + (f" and {len(spec.materials.svbrdf_folders)} imported folder(s)" if spec.materials.svbrdf_folders else "")
        + ".",
        f"- **Flagged renders** (NaN, infinite or negative pixels after every retry, kept and flagged): "
        f"{len(flagged)}"
        + (": " + ", ".join(f"`{i}`" for i in flagged[:20]) if flagged else "")
        + (" ..." if len(flagged) > 20 else "")
        + ".",
        "",
        "**Effects left out** of a scene where the material does not need them (the image is the same to "
        "float32 rounding or bit for bit; the specular lobe is never left out):",
        "",
        "| effect | samples rendered without it |",
        "|---|---|",
        *left_out,
        "",
        "<details><summary>The spec</summary>",
        "",
        "```toml",
        *_spec_lines(facts),
        "```",
        "",
        "</details>",
        "",
    ]
    return lines


def _spec_lines(facts: PublicationFacts) -> list[str]:
    return spec_to_toml(facts.spec).rstrip("\n").split("\n")


def files_section(facts: PublicationFacts) -> list[str]:
    tar_total = sum(t.bytes for t in facts.tars)
    rows = [
        f"| `{t.path}` | {_mb(t.bytes)} | samples `{t.first}` to `{t.last}` ({t.samples}), {t.members} members |"
        for t in facts.tars
    ]
    return [
        "## Files",
        "",
        "| file | size | what |",
        "|---|---|---|",
        *rows,
        f"| `{SAMPLES_FILE}` | {_mb(facts.sizes[SAMPLES_FILE])} | one row per sample (the table above) |",
        f"| `{SOURCE_FILES['spec.toml']}`, `{SOURCE_FILES['dataset.json']}`, `{SOURCE_FILES['manifest.jsonl']}`, "
        f"`{MARKERS_REL}` | "
        f"{_mb(sum(facts.sizes[r] for r in (*SOURCE_FILES.values(), MARKERS_REL)))} | the source folder's "
        "spec, description, manifest and shard markers, byte for byte |",
        f"| `{INDEX_FILE}` | {_mb(facts.sizes[INDEX_FILE])} | publication format and the tar shards |",
        f"| `{CROISSANT_FILE}` | {_mb(facts.sizes[CROISSANT_FILE])} | Croissant 1.1 metadata |",
        *(
            [f"| `{PREVIEW_FILE}` | {_mb(facts.sizes[PREVIEW_FILE])} | the contact sheet |"]
            if facts.has_preview
            else []
        ),
        f"| `{SUMS_FILE}` | | SHA-256 of every other file: `sha256sum -c {SUMS_FILE}` |",
        "",
        f"Tars: {_mb(tar_total)} for {_mb(facts.member_bytes)} of members (ustar headers and padding: "
        f"{_mb(tar_total - facts.member_bytes)}). Storing each material's maps with every lighting instead "
        f"would add {_mb(facts.repeated_maps_extra_bytes)}. The source folder is {_mb(facts.source_bytes)}.",
        "",
    ]


def load_section(spec) -> list[str]:
    return [
        "## How to load it",
        "",
        "### With shaderball",
        "",
        "```sh",
        "shaderball verify .                 # every checksum and every tar member, nothing extracted",
        "shaderball unpack . --out DIR       # the source dataset folder, byte for byte; then validated",
        "shaderball validate DIR",
        "```",
        "",
        "```python",
        LOAD_WITH_SHADERBALL.rstrip("\n"),
        "```",
        "",
        "### With Hugging Face `datasets`",
        "",
        "The card's `configs` declare each column's type: the previews are `Image` columns (what the Hub's "
        "viewer shows), the EXR files bytes, the record and the material's row typed structs. A row's EXR "
        "bytes become float arrays in two lines (OpenEXR's Python package groups `render.R/G/B` into one "
        "(H, W, 3) array named `render`), once `checked_exr` (in each recipe below) has read the header. "
        "OpenEXR decodes whatever a header says (a 2 MB render can declare 20000 x 20000 pixels, or list "
        "its channels twice, which OpenEXR merges): each recipe refuses an EXR member whose header says "
        f"anything but this spec's {spec.render.resolution} x {spec.render.resolution} pixels of the "
        "member's channels before it decodes a pixel.",
        "",
        "```py",
        EXR_TWO_LINES.rstrip("\n"),
        "```",
        "",
        "```python",
        recipe(LOAD_WITH_DATASETS, spec).rstrip("\n"),
        "```",
        "",
        '`datasets.load_dataset("webdataset", data_files=...)` on the tars of one kind works too, with types '
        "guessed from the first rows (a field null in all of them is dropped: use the card's configs).",
        "",
        "### With webdataset",
        "",
        "```python",
        recipe(LOAD_WITH_WEBDATASET, spec).rstrip("\n"),
        "```",
        "",
        "### With tarfile and OpenEXR",
        "",
        "The tars are plain ustar. Read members as a stream; never `extractall` an archive you did not write "
        "(Python before 3.11.13/3.12.11 has path-traversal bugs in `tarfile`); run `shaderball verify` first "
        "on a copy you received.",
        "",
        "```python",
        recipe(LOAD_WITH_TARFILE, spec).rstrip("\n"),
        "```",
        "",
    ]


def dataset_card(facts: PublicationFacts) -> str:
    spec = facts.spec
    counts = facts.description.get("counts") or {}
    materials = counts.get("materials", facts.materials)
    intro = [
        f"# shaderball dataset `{facts.name}` (version {facts.description.get('version', '?')})",
        "",
        scene_card.intro_text(facts, materials)
        if scene_card.has_scene(facts)
        else f"{facts.summary.samples} path-traced renders of a shaderball, {materials} "
        f"materials under {spec.dataset.lights_per_material} sun-and-sky lightings each, with the material "
        "maps and lighting vector each render was made from: the data of *A Flexible Neural Renderer for "
        "Material Visualization* (KT, Sakurikar, Saini, Narayanan; SIGGRAPH Asia 2019 Technical Briefs), "
        "built with shaderball and Mitsuba 3.",
        "",
    ]
    if facts.has_preview:
        intro += [
            f"![contact sheet: renders beside their diffuse, specular, roughness and normal maps]({PREVIEW_FILE})",
            "",
        ]
    citation = ["## Citation", "", "```bibtex", CITATION, "```", ""]
    lines = (
        yaml_header(facts)
        + intro
        + sample_section(facts)
        + scene_card.scene_section(facts)
        + made_section(facts)
        + files_section(facts)
        + load_section(spec)
        + citation
    )
    return "\n".join(lines)
