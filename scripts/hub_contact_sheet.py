"""A contact sheet of a publication's previews laid out as the Hugging Face viewer shows the
``renders`` config joined with ``materials``: one row per sample, its key, its
``render.png``, its material's ``maps.png`` and a few ``json`` cells.

    python scripts/hub_contact_sheet.py PUB docs/img/hub-viewer.png [--rows 16]

Every preview is read through pipeline.publish's reader (each tar's SHA-256, headers and
members checked; nothing extracted), then decoded by materials.imagefile only if its header
says it is the size publish writes (a render's preview ``side`` x ``side``, a strip four
times as wide); any other is drawn as a grey tile and named on stderr. The picture is a pure
function of the publication (and of Pillow's default font). docs/publish.md shows the smoke
publication's.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import sys

from PIL import Image, ImageDraw, ImageFont

from materials.errors import MaterialError
from materials.imagefile import read_image
from pipeline.publish.names import MATERIALS, RENDERS, TAR_NAME
from pipeline.publish.previews import PREVIEW_SIDE, preview_factor
from pipeline.publish.reader import open_publication

ROW_GAP = 6
HEADER = 30
BACKGROUND = (255, 255, 255)
RULE = (229, 231, 235)
TEXT = (17, 24, 39)
MUTED = (107, 114, 128)
HEAD_BG = (249, 250, 251)
PLACEHOLDER = (156, 163, 175)


def _font(size: int):
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1
        return ImageFont.load_default()


def previews(pub: str) -> tuple[list[dict], dict[str, bytes], int]:
    """(the renders' cells in order, material id -> maps.png, the side of a render's preview
    as publish writes it), every member checked."""
    publication = open_publication(pub)
    shape = publication.exr_bounds["render"].shape
    side = PREVIEW_SIDE if shape is None else shape[0] // preview_factor(shape[0])
    rows, strips = [], {}
    before = 0
    for tar in publication.tars:
        kind = TAR_NAME.match(tar.rel).group(1)
        record = None
        for expected, data in publication.members(tar, before):
            if kind == MATERIALS and expected.name.endswith(".maps.png"):
                strips[expected.material_id] = data
            elif kind == RENDERS and expected.role == "record":
                record = json.loads(data)
            elif kind == RENDERS and expected.name.endswith(".render.png"):
                rows.append({"key": expected.sample_id, "record": record, "png": data})
        before += tar.count
    return rows, strips, side


def tile(data: bytes | None, label: str, width: int, height: int, problems: list[str]) -> Image.Image:
    """The preview ``data`` if it is a ``width`` x ``height`` image, else a grey tile (and why
    goes to ``problems``): its size is read from its header before anything is decoded."""
    try:
        if data is None:
            raise MaterialError(f"{label}: no such preview")
        pixels, _full_scale = read_image(data, label, width, height)
        picture = Image.fromarray(pixels).convert("RGB")
        if picture.size != (width, height):
            raise MaterialError(
                f"{label}: the image is {picture.size[0]} x {picture.size[1]}, expected {width} x {height}"
            )
        return picture
    except MaterialError as exc:
        problems.append(str(exc))
        return Image.new("RGB", (width, height), PLACEHOLDER)


def _number(value, digits: int) -> str:
    return f"{value:.{digits}f}" if isinstance(value, (int, float)) and not isinstance(value, bool) else "?"


def sheet(pub: str, count: int, problems: list[str]) -> Image.Image:
    rows, strips, side = previews(pub)
    return sheet_of(rows[:count], strips, side, problems)


def sheet_of(rows: list[dict], strips: dict[str, bytes], side: int, problems: list[str]) -> Image.Image:
    """The sheet of ``rows`` (as :func:`previews` gives them) with previews ``side`` pixels a
    side; a preview of any other size, or one that cannot be read, is a grey tile named in
    ``problems``."""
    columns = [
        ("__key__", 120),
        ("render.png", side + 16),
        ("maps.png (materials, by material_id)", 4 * side + 16),
        ("json.lighting", 190),
        ("json.material", 150),
    ]
    width = sum(w for _, w in columns)
    height = HEADER + len(rows) * (side + ROW_GAP)
    picture = Image.new("RGB", (width, height), BACKGROUND)
    draw = ImageDraw.Draw(picture)
    font, small = _font(13), _font(12)
    draw.rectangle([0, 0, width, HEADER - 1], fill=HEAD_BG)
    x = 0
    for name, w in columns:
        draw.text((x + 8, 8), name, fill=TEXT, font=font)
        x += w
    for number, row in enumerate(rows):
        y = HEADER + number * (side + ROW_GAP)
        draw.line([0, y, width, y], fill=RULE)
        record = row["record"] if isinstance(row["record"], dict) else {}
        lighting = record.get("lighting") if isinstance(record.get("lighting"), dict) else {}
        material = record.get("material") if isinstance(record.get("material"), dict) else {}
        cells = [
            [row["key"]],
            None,
            None,
            [
                f"elevation {_number(lighting.get('elevation_deg'), 1)} deg",
                f"azimuth {_number(lighting.get('azimuth_deg'), 1)} deg",
                f"turbidity {_number(lighting.get('turbidity'), 2)}",
            ],
            [str(material.get("kind", "?")), str(material.get("family") or "")],
        ]
        x = 0
        for (name, w), cell in zip(columns, cells):
            if name == "render.png":
                image = tile(row["png"], f"{row['key']}.render.png", side, side, problems)
                picture.paste(image, (x + 8, y + ROW_GAP // 2))
            elif name.startswith("maps.png"):
                material_id = str(record.get("material_id"))
                image = tile(strips.get(material_id), f"{material_id}.maps.png", 4 * side, side, problems)
                picture.paste(image, (x + 8, y + ROW_GAP // 2))
            else:
                for i, line in enumerate(cell):
                    draw.text((x + 8, y + 6 + 16 * i), line, fill=TEXT if i == 0 else MUTED, font=small)
            x += w
    return picture


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("pub")
    parser.add_argument("out")
    parser.add_argument("--rows", type=int, default=16)
    args = parser.parse_args()
    if not os.path.isdir(args.pub):  # every argument before the sheet is drawn or written
        parser.error(f"PUB {args.pub}: not a folder (a publication `shaderball publish` wrote)")
    if os.path.isdir(args.out) or not os.path.isdir(os.path.dirname(os.path.abspath(args.out))):
        parser.error(f"OUT {args.out}: is a folder, or its folder does not exist (a PNG file to write)")
    if not 1 <= args.rows <= 10_000:
        parser.error(f"--rows: {args.rows} is not allowed; allowed: 1 to 10000")
    problems: list[str] = []
    buffer = io.BytesIO()
    sheet(args.pub, args.rows, problems).save(buffer, format="PNG", optimize=True)
    with open(args.out, "wb") as fh:
        fh.write(buffer.getvalue())
    for problem in problems:
        print(f"{args.pub}: {problem}; drawn as a grey tile", file=sys.stderr)
    print(f"{args.out}: {len(buffer.getvalue())} bytes")


if __name__ == "__main__":
    main()
