"""What the dataset card (pipeline.publish.card) says of a publication whose samples are on
other objects or under environment maps (pipeline.publish.scene_fields): the scene columns,
the geometry layers of the maps file, the objects and maps with their digests, and why and
how meshes and maps travel by digest, not in the publication.

Every function gives nothing (or the card's own text) for a shaderball-and-sun publication,
whose card is byte for byte what it was before objects existed.
"""

from __future__ import annotations

import os

from pipeline.publish.publication_facts import PublicationFacts
from pipeline.publish.scene_fields import ENVIRONMENT, SCENE_COLUMN_DOCS, has_scene_columns
from pipeline.store.exr import GEOMETRY_LAYERS, LAYER_CHANNELS

#: What each geometry layer of a maps file holds.
GEOMETRY_DOCS = {
    "geometry_normal": "the object's world-space shading normal: interpolated vertex normals, before any normal "
    "map, unit inside the mask",
    "depth": "metres from the camera plane along the view axis",
}


def has_scene(facts: PublicationFacts) -> bool:
    return has_scene_columns(facts.description)


def _environment_lit(facts: PublicationFacts) -> bool:
    return facts.spec.lighting.source == ENVIRONMENT


def geometry_layers(spec) -> tuple[str, ...]:
    """The geometry layers the spec stores in each maps file (``storage.layers``)."""
    return tuple(layer for layer in GEOMETRY_LAYERS if layer in spec.storage.layers)


def geometry_text(spec) -> str:
    """The maps member's geometry layers, for the card's table (empty where none is stored)."""
    layers = geometry_layers(spec)
    if not layers:
        return ""
    named = "; ".join(f"`{layer}.{'/'.join(LAYER_CHANNELS[layer])}` ({GEOMETRY_DOCS[layer]})" for layer in layers)
    return f"; the object's geometry: {named}, float32, 0 outside the mask"


def intro_text(facts: PublicationFacts, materials) -> str:
    """The card's first paragraph for a publication with the scene columns."""
    lights = "environment-map" if _environment_lit(facts) else "sun-and-sky"
    objects = ", ".join(f"`{name}`" for name in facts.summary.scene.objects)
    return (
        f"{facts.summary.samples} path-traced renders of {materials} materials on objects ({objects}) under "
        f"{facts.spec.dataset.lights_per_material} {lights} lightings each, with the material maps, the object's "
        "geometry and the lighting vector each render was made from, built with shaderball and Mitsuba 3 after "
        "*A Flexible Neural Renderer for Material Visualization* (KT, Sakurikar, Saini, Narayanan; SIGGRAPH Asia "
        "2019 Technical Briefs), which used the shaderball and a sun and sky."
    )


def column_lines(facts: PublicationFacts) -> list[str]:
    """The scene columns' rows of the card's column table (none for a default publication)."""
    if not has_scene(facts):
        return []
    return [f"| `{c}` | {t.split(':')[1]} | {d} |" for c, t, d in SCENE_COLUMN_DOCS]


def lighting_vector_text(facts: PublicationFacts) -> str:
    """The card's sentence on the network's lighting input."""
    sun = "the unit sun direction (3) and the turbidity"
    if _environment_lit(facts):
        return (
            "The network's lighting input is the record's `lighting_vector`, as float32: under an environment map "
            "the direction of the map's centre (x, y, 0) and log2 of its scale; the map itself is named by "
            "`environment` and its SHA-256."
        )
    return f"The network's lighting input is the record's `lighting_vector`: {sun}, as float32."


def made_lines(facts: PublicationFacts) -> list[str]:
    """The card's "How it was made" bullets on objects and environment lighting."""
    if not has_scene(facts):
        return []
    spec, scene = facts.spec, facts.summary.scene
    drawn = ", ".join(f"`{name}` {entry['samples']}" for name, entry in scene.objects.items())
    lines = [
        f"- **Objects**: {', '.join(f'`{os.path.basename(o)}`' for o in spec.scene.objects)}, one per material (scheme "
        f"`{spec.scene.scheme}`), each scaled into the shaderball's box and framed by its camera rule; "
        f"renders per object: {drawn}.",
    ]
    if _environment_lit(facts):
        lines.append(
            f"- **Environment lighting**: {len(scene.environments)} lat-long HDR map(s), one drawn per lighting, "
            f"rotated about the vertical by {spec.lighting.rotation_deg[0]:g} to {spec.lighting.rotation_deg[1]:g} "
            f"deg and scaled by {spec.lighting.intensity[0]:g} to {spec.lighting.intensity[1]:g}; rendered: "
            f"rotation {_span(scene.rotation_deg)} deg, scale {_span(scene.scale)}; no sun or sky."
        )
    return lines


def subject(facts: PublicationFacts) -> str:
    """What a render shows: the shaderball, or (with the scene columns) the material's object."""
    return "its object" if has_scene(facts) else "the shaderball"


def sun_lines(facts: PublicationFacts, line: str) -> list[str]:
    """The card's sun bullet ``line``, left out under environment maps (no sun was rendered)."""
    return [] if _environment_lit(facts) else [line]


def _span(span) -> str:
    return f"{span[0]:.3g} to {span[1]:.3g}" if span is not None else "none"


def scene_section(facts: PublicationFacts) -> list[str]:
    """``## Objects and environment maps``: what each is, with its digest, and how they travel."""
    if not has_scene(facts):
        return []
    scene = facts.summary.scene
    objects = [
        f"| `{name}` | {entry['kind'] or 'built in'} | {_digest(entry['sha256'])} | {_digest(entry['file_sha256'])} "
        f"| {entry['uv_source'] or 'built in'} | {entry['samples']} |"
        for name, entry in scene.objects.items()
    ]
    lines = [
        "## Objects and environment maps",
        "",
        "Each sample names its object and its light: the columns `object` to `environment_scale` above, and the "
        "record's `object` and `lighting` fields (a shaderball sample's record has no `object`; a sun-lit one's "
        'lighting has no `source`). With `datasets` they are `row["json"]["object"]` and '
        '`row["json"]["lighting"]`; shaderball\'s torch loader (`pipeline.neural.data.open_dataset`, which '
        "reads this folder) gives each sample's `object`, `light_source` and `environment`, and the geometry layers "
        "stored as `geometry_normal` (3, R, R) and `depth` (1, R, R) tensors.",
        "",
        "| object | kind | mesh SHA-256 | file SHA-256 | UVs | renders |",
        "|---|---|---|---|---|---|",
        *objects,
        "",
    ]
    if scene.environments:
        lines += [
            "| environment map | SHA-256 | renders |",
            "|---|---|---|",
            *(f"| `{name}` | `{e['sha256']}` | {e['samples']} |" for name, e in sorted(scene.environments.items())),
            "",
        ]
    return lines + [
        "**Meshes and environment maps are not in this publication: they travel by digest.** Each record carries "
        "the SHA-256 of its object's canonical mesh (`object.sha256`, and the mesh file's, `object.file_sha256`) "
        "and of its environment map's file (`lighting.sha256`). Third-party meshes and HDRIs carry their own "
        "licences, which may not let a dataset's publisher pass them on; maps are large (a float 4096 x 2048 map is about 100 MB); "
        f"and the renders and the maps file's layers (`mask`{_geometry_names(facts.spec)}) already hold what "
        "training needs. Whoever has the files checks them against the digests (`sha256sum FILE` prints the "
        "file's); `dataset/dataset.json` lists, under `sources`, each file the spec named (by its path on the "
        "machine that built it) with its SHA-256, and a rebuild from `dataset/spec.toml` needs the same files.",
        "",
    ]


def _digest(value) -> str:
    return f"`{value}`" if value else "-"


def _geometry_names(spec) -> str:
    return "".join(f", `{layer}`" for layer in geometry_layers(spec))
