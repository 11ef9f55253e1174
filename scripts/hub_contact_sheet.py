"""A contact sheet of a publication's previews laid out as the Hugging Face viewer shows the
``renders`` config joined with ``materials``: one row per sample, its key, its
``render.png``, its material's ``maps.png`` and a few ``json`` cells.

    python scripts/hub_contact_sheet.py PUB docs/img/hub-viewer.png [--rows 16]

Every preview is read through pipeline.publish's reader (each tar's SHA-256, headers and
members checked; nothing extracted). The picture is a pure function of the publication
(and of Pillow's default font). docs/publish.md shows the smoke publication's.
"""

from __future__ import annotations

import argparse
import io
import json

from PIL import Image, ImageDraw, ImageFont

from pipeline.publish.names import MATERIALS, RENDERS, TAR_NAME
from pipeline.publish.reader import open_publication

ROW_GAP = 6
HEADER = 30
BACKGROUND = (255, 255, 255)
RULE = (229, 231, 235)
TEXT = (17, 24, 39)
MUTED = (107, 114, 128)
HEAD_BG = (249, 250, 251)


def _font(size: int):
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1
        return ImageFont.load_default()


def previews(pub: str) -> tuple[list[dict], dict[str, bytes]]:
    """(the renders' cells in order, material id -> maps.png), every member checked."""
    publication = open_publication(pub)
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
        before += len(tar.expected)
    return rows, strips


def sheet(pub: str, count: int) -> Image.Image:
    rows, strips = previews(pub)
    rows = rows[:count]
    with Image.open(io.BytesIO(rows[0]["png"])) as first:
        side = first.size[1]
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
        record = row["record"]
        lighting, material = record["lighting"], record["material"]
        cells = [
            [row["key"]],
            None,
            None,
            [
                f"elevation {lighting['elevation_deg']:.1f} deg",
                f"azimuth {lighting['azimuth_deg']:.1f} deg",
                f"turbidity {lighting['turbidity']:.2f}",
            ],
            [material["kind"], material.get("family") or ""],
        ]
        x = 0
        for (name, w), cell in zip(columns, cells):
            if name == "render.png":
                with Image.open(io.BytesIO(row["png"])) as image:
                    picture.paste(image.convert("RGB"), (x + 8, y + ROW_GAP // 2))
            elif name.startswith("maps.png"):
                with Image.open(io.BytesIO(strips[record["material_id"]])) as image:
                    picture.paste(image.convert("RGB"), (x + 8, y + ROW_GAP // 2))
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
    buffer = io.BytesIO()
    sheet(args.pub, args.rows).save(buffer, format="PNG", optimize=True)
    with open(args.out, "wb") as fh:
        fh.write(buffer.getvalue())
    print(f"{args.out}: {len(buffer.getvalue())} bytes")


if __name__ == "__main__":
    main()
