"""`shaderball preview DIR --out FILE.png`: a contact sheet of a dataset, for people.

One row per chosen sample: its label (id, material, sun elevation / azimuth, turbidity; under
an environment map its base name, rotation and scale; where the dataset shows materials on
objects other than the shaderball, the sample's object), its render tone-mapped (pipeline.image.tonemap.preview_srgb8: exposure from the ball's pixels, Reinhard,
sRGB), then its four screen-space maps as the network sees them: diffuse and specular
albedo (sRGB-encoded for display), roughness (grey, raw) and the tangent-space normal
((n + 1) / 2, raw). Samples are spread evenly over the renders recorded so far, so it
works on a partial build. Never used for data: the PNG is 8-bit and tone-mapped.
"""

from __future__ import annotations

import os
from array import array
from dataclasses import dataclass

import numpy as np

from pipeline.check.info import problems_line, shard_render_counts
from pipeline.check.request import DATASET_FOLDER, PreviewRequest, dir_refused
from pipeline.check.snapshot import read_snapshot
from pipeline.dataset.spec import DEFAULT_OBJECTS
from pipeline.errors import ShaderballError
from pipeline.image.tonemap import map_srgb8, preview_srgb8
from pipeline.store.atomic import write_bytes_atomic
from pipeline.store.bounded_read import OverBound, Recorded, read_bytes, resolve_inside, unsafe_entry
from pipeline.store.exr import ROLE_LAYERS, layer_bounds, read_exr
from pipeline.store.folder import manifest_record_count, shard_records
from pipeline.store.layout import Layout

COLUMNS = ("render", "diffuse", "specular", "roughness", "normal")
LABEL_WIDTH = 190
#: A label's line height (px), and the most lines drawn at it: a sun-lit sample on the shaderball
#: has at most this many, so its label is drawn as it always was; a longer one is packed into its row.
LINE_STEP = 17
FULL_STEP_LINES = 7
#: Characters of an object's name shown (a mesh file's name may be long).
NAME_CHARS = 24
HEADER_HEIGHT = 22
GAP = 4
BACKGROUND = (24, 24, 24)
MISSING_TILE = (60, 60, 60)


@dataclass(frozen=True)
class PreviewSummary:
    out: str
    samples: list[str]
    recorded: int
    total: int
    size: tuple[int, int]
    #: records left out, and why (malformed, or naming a path that leaves the folder), and
    #: files of the chosen samples that could not be read or decoded (their tiles "unreadable")
    problems: tuple[str, ...] = ()
    #: shards whose marker marks them complete, of all planned, and the manifest's records
    shards_complete: int = 0
    shards: int = 0
    manifest_records: int | None = None

    @property
    def exit_code(self) -> int:
        """1 when something was left out (validate's "problems found"; the sheet is written)."""
        return 1 if self.problems else 0

    @property
    def complete(self) -> bool:
        return self.shards_complete == self.shards and self.manifest_records == self.total

    def lines(self) -> list[str]:
        state = (
            ""
            if self.complete
            else f"; INCOMPLETE: {self.shards_complete}/{self.shards} shards complete, manifest.jsonl "
            + ("absent" if self.manifest_records is None else f"{self.manifest_records} records")
        )
        out = [
            f"contact sheet {self.out}: {len(self.samples)} samples "
            f"({self.recorded}/{self.total} renders recorded), {self.size[0]}x{self.size[1]} px{state}",
            "samples: " + ", ".join(self.samples),
        ]
        if self.problems:
            out.append(problems_line("left out", self.problems))
        return out


def choose_samples(records: list[dict], count: int) -> list[dict]:
    """``count`` records spread evenly over ``records`` (sorted by id), first and last included."""
    return [records[i] for i in choose_indices([r["id"] for r in records], count)]


def choose_indices(ids: list[str], count: int) -> list[int]:
    """Positions in ``ids`` of ``count`` ids spread evenly over them sorted (ties in their
    order), first and last included: what :func:`choose_samples` picks, from the ids alone."""
    order = sorted(range(len(ids)), key=ids.__getitem__)
    if len(order) <= count:
        return order
    picks = np.unique(np.round(np.linspace(0, len(order) - 1, count)).astype(int))
    return [order[i] for i in picks]


def map_tiles(layers: dict[str, np.ndarray]) -> dict[str, np.ndarray | None]:
    """uint8 (H, W, 3) pictures of the maps of a ``maps.exr`` (None for a layer not stored)."""

    def grey(x):
        return np.repeat(x.reshape(x.shape[0], x.shape[1], 1), 3, axis=-1)

    out: dict[str, np.ndarray | None] = {}
    for name in ("diffuse", "specular"):
        out[name] = map_srgb8(layers[name].astype(np.float32), srgb=True) if name in layers else None
    rough = layers.get("roughness")
    out["roughness"] = grey(map_srgb8(rough.astype(np.float32), srgb=False)) if rough is not None else None
    normal = layers.get("normal")
    if normal is not None:
        encoded = (normal.astype(np.float32) + 1.0) * 0.5
        mask = layers.get("mask")
        if mask is not None:
            encoded = np.where(mask.reshape(mask.shape[0], mask.shape[1], 1) > 0.5, encoded, 0.0)
        out["normal"] = map_srgb8(encoded, srgb=False)
    else:
        out["normal"] = None
    return out


def _dict(value) -> dict:
    return value if isinstance(value, dict) else {}


def _num(value) -> float:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else float("nan")


def label_text(record: dict, show_object: bool = False) -> list[str]:
    """The lines of a sample's label. ``show_object``: also the object it is shown on (the
    record's ``object.name``; a record without one is on the shaderball)."""
    material = _dict(record.get("material"))
    kind = str(material.get("kind", "?"))
    if kind == "svbrdf":
        file = material.get("file")
        source = material.get("family") or (os.path.basename(file) if isinstance(file, str) else "") or "?"
        kind = f"SVBRDF {source}"
    lines = [str(record["id"]), kind]
    if show_object:
        lines.append(f"on {object_label(record)}")
    lines += light_label(_dict(record.get("lighting")))
    if _dict(record.get("stats")).get("flagged"):
        lines.append("FLAGGED: bad pixels")
    return lines


def object_label(record: dict) -> str:
    """The object a record names (``object.name``), shortened to :data:`NAME_CHARS`."""
    name = _dict(record.get("object")).get("name", DEFAULT_OBJECTS[0])
    name = name if isinstance(name, str) else "?"
    return name if len(name) <= NAME_CHARS else name[: NAME_CHARS - 3] + "..."


def light_label(lighting: dict) -> list[str]:
    """A record's lighting as a label says it: the environment map's base name, rotation and
    scale, or the sun's elevation, azimuth and turbidity (and the elevation asked for, where the
    low-sun policy raised it)."""
    if lighting.get("source") == "environment":
        file = lighting.get("file")
        name = file if isinstance(file, str) else "?"
        return [
            f"map {name if len(name) <= NAME_CHARS else name[: NAME_CHARS - 3] + '...'}",
            f"rotation {_num(lighting.get('rotation_deg')):.1f} deg",
            f"scale {_num(lighting.get('scale')):.2f}",
        ]
    lines = [
        f"sun elevation {_num(lighting.get('elevation_deg')):.1f} deg",
        f"sun azimuth {_num(lighting.get('azimuth_deg')):.1f} deg",
        f"turbidity {_num(lighting.get('turbidity')):.2f}",
    ]
    requested = _dict(lighting.get("requested"))
    if requested and abs(_num(requested.get("elevation_deg")) - _num(lighting.get("elevation_deg"))) > 1e-9:
        lines.append(f"(raised from {_num(requested.get('elevation_deg')):.1f} deg)")
    return lines


def line_step(lines: int, tile: int) -> int:
    """Pixels between a label's lines: :data:`LINE_STEP`, or less for a label longer than
    :data:`FULL_STEP_LINES` lines, so that it stays in its row."""
    if lines <= FULL_STEP_LINES:
        return LINE_STEP
    return max(11, min(LINE_STEP, (tile + GAP - 8) // lines))


def _read_layers(root: str, entry: dict, layer: str | None, resolution: int) -> dict:
    """The layers of the EXR a record's file ``entry`` names, read only inside the folder
    (pipeline.store.bounded_read.resolve_inside), only at the size the record gives it, and decoded
    only if its header says it is ``resolution`` pixels a side, with no more channels than a
    render (``layer`` "render") or a maps file holds (pipeline.store.exrheader);
    ShaderballError naming it otherwise."""
    rel = entry["path"]
    try:
        data = read_bytes(resolve_inside(root, rel), Recorded(entry["bytes"]))
    except OverBound as exc:  # validate's size_mismatch, in its words
        raise ShaderballError(f"{rel}: {exc.strerror}; run `shaderball validate`") from None
    except OSError as exc:
        raise ShaderballError(f"{rel}: cannot be read ({exc.strerror}); run `shaderball validate`") from None
    role = "render" if layer == "render" else "maps"
    layers = read_exr(data, rel, layer_bounds(resolution, ROLE_LAYERS[role], exact=True)).layers
    if layer is not None and layer not in layers:
        raise ShaderballError(f"{rel}: holds no {layer} layer; run `shaderball validate`")
    return layers


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: the fixed bitmap font
        return ImageFont.load_default()


def _fit(picture: np.ndarray, tile: int):
    from PIL import Image

    image = Image.fromarray(picture)
    if image.size == (tile, tile):
        return image
    upscale = tile >= image.size[0] and tile % image.size[0] == 0
    return image.resize((tile, tile), Image.NEAREST if upscale else Image.LANCZOS)


def _tile_layers(root: str, entry: dict | None, layer: str | None, resolution: int, problems: list[str]) -> dict | None:
    """The layers of one tile's file (a record's file entry), or None (the tile is marked
    unreadable and the reason added to ``problems``) when it cannot be read or decoded: one
    bad file spoils one tile, not the sheet."""
    if entry is None:
        return {}
    try:
        return _read_layers(root, entry, layer, resolution)
    except ShaderballError as exc:
        problems.append(str(exc))
        return None


def _unreadable(draw, x: int, y: int, tile: int, text: str, font) -> None:
    draw.rectangle([x, y, x + tile - 1, y + tile - 1], fill=MISSING_TILE)
    draw.text((x + 6, y + 6), text, fill=(200, 200, 200), font=font)


def contact_sheet(
    root: str,
    records: list[dict],
    tile: int,
    resolution: int,
    problems: list[str] | None = None,
    show_objects: bool = False,
) -> np.ndarray:
    """The sheet as uint8 (H, W, 3): a header, then one row per record. A file that cannot
    be read or decoded, or is not ``resolution`` pixels a side, gets an "unreadable" tile,
    and why goes to ``problems``. ``show_objects``: every label names its sample's object."""
    problems = [] if problems is None else problems
    from PIL import Image, ImageDraw

    width = LABEL_WIDTH + len(COLUMNS) * (tile + GAP) + GAP
    height = HEADER_HEIGHT + len(records) * (tile + GAP) + GAP
    sheet = Image.new("RGB", (width, height), BACKGROUND)
    draw = ImageDraw.Draw(sheet)
    font, small = _font(14), _font(12)
    for c, name in enumerate(COLUMNS):
        draw.text((LABEL_WIDTH + c * (tile + GAP) + GAP, 4), name, fill=(230, 230, 230), font=font)
    cache: dict[str, dict] = {}
    for r, record in enumerate(records):
        y = HEADER_HEIGHT + r * (tile + GAP)
        files = {entry["role"]: entry for entry in record["files"]}
        render = _tile_layers(root, files["render"], "render", resolution, problems)
        maps = files.get("maps")
        maps_rel = None if maps is None else maps["path"]
        if maps_rel not in cache:
            cache[maps_rel] = _tile_layers(root, maps, None, resolution, problems)
        layers = cache[maps_rel]
        mask = (layers or {}).get("mask")
        mask = mask[..., 0] > 0.5 if mask is not None else None
        pictures = {"render": None if render is None else preview_srgb8(render["render"], mask=mask)}
        pictures.update(map_tiles(layers) if layers is not None else {})
        for c, name in enumerate(COLUMNS):
            x = LABEL_WIDTH + c * (tile + GAP) + GAP
            if pictures.get(name) is None:
                broken = (render is None) if name == "render" else (layers is None)
                _unreadable(draw, x, y, tile, "unreadable" if broken else "not stored", small)
            else:
                sheet.paste(_fit(pictures[name], tile), (x, y))
        label = label_text(record, show_objects)
        step = line_step(len(label), tile)
        for i, line in enumerate(label):
            draw.text(
                (8, y + 4 + step * i),
                line,
                fill=(235, 235, 235) if i == 0 else (190, 190, 190),
                font=font if i == 0 else small,
            )
    return np.asarray(sheet)


def _read_chosen(layout: Layout, counts: dict[str, int], places: list[int]) -> list[dict]:
    """The records at ``places`` (shard number << 32 | position among its records), in that
    order, reading each shard once and holding one shard's records at a time."""
    shards = list(counts.items())
    chosen: dict[int, dict] = {}
    current, found = None, []
    for place in sorted(set(places)):
        index, position = place >> 32, place & 0xFFFFFFFF
        if index != current:
            current, found = index, shard_records(layout, shards[index][0], shards[index][1])[0]
        if position >= len(found):
            raise dir_refused(
                layout.root, f"changed while it was previewed (shard {shards[index][0]})", owner=PreviewRequest
            )
        chosen[place] = found[position]
    return [chosen[place] for place in places]


def write_preview(request: PreviewRequest) -> PreviewSummary:
    """Write the contact sheet of the dataset ``request.directory`` to the PNG ``request.out``."""
    from PIL import Image

    root, out, samples, tile = request.directory, request.out, request.rows, request.tile
    layout = Layout(root)
    if not os.path.isdir(root) or not os.path.lexists(layout.spec):
        raise dir_refused(root, "is not a dataset folder", f"{DATASET_FOLDER} (with its spec.toml)", PreviewRequest)
    spec = read_snapshot(root)
    counts = shard_render_counts(spec)
    # One shard's records at a time; of each usable one, its id and where it was found (a
    # compact index), then the chosen few are read again.
    ids, where, problems, complete = [], array("l"), [], 0
    show_objects = False  # any record names its object: then every label does
    for index, (shard, renders) in enumerate(counts.items()):
        found, shard_complete, _started, left_out = shard_records(layout, shard, renders)
        complete += shard_complete
        problems += left_out
        for position, record in enumerate(found):
            unsafe = next((why for e in record["files"] if (why := unsafe_entry(root, e["path"]))), None)
            if unsafe:
                problems.append(f"record {record['id']}: {unsafe}")
            else:
                ids.append(record["id"])
                where.append(index << 32 | position)
                show_objects = show_objects or "object" in record
    if not ids:
        raise dir_refused(
            root,
            "holds no finished render yet" + (f" ({len(problems)} left out: {problems[0]})" if problems else ""),
            "a dataset with at least one finished render; nothing to preview",
            PreviewRequest,
        )
    chosen = _read_chosen(layout, counts, [where[i] for i in choose_indices(ids, samples)])
    resolution = spec.render.resolution
    if tile is None:
        tile = resolution * max(1, -(-128 // resolution)) if resolution < 128 else min(resolution, 256)
    picture = contact_sheet(root, chosen, tile, resolution, problems, show_objects)
    import io

    buffer = io.BytesIO()
    Image.fromarray(picture).save(buffer, format="PNG", optimize=True)
    folder = os.path.dirname(os.path.abspath(out))
    os.makedirs(folder, exist_ok=True)
    write_bytes_atomic(out, buffer.getvalue())
    return PreviewSummary(
        out=out,
        samples=[r["id"] for r in chosen],
        recorded=len(ids),
        total=sum(counts.values()),
        size=(picture.shape[1], picture.shape[0]),
        problems=tuple(problems),
        shards_complete=complete,
        shards=len(counts),
        manifest_records=manifest_record_count(layout, sum(counts.values())),
    )
