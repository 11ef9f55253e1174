"""Which EXR readers installed here read a dataset's files: a render, a material's screen-space
maps and its texture maps. One line per (reader, file): OK with what it returned, or FAILS
with the reader's own message (docs/publish.md, "EXR readers").

    python scripts/exr_readers.py DIR

imageio's FreeImage plugin needs the FreeImage library: name it with IMAGEIO_FREEIMAGE_LIB
(e.g. Debian's libfreeimage3 unpacked with ``apt-get download`` + ``dpkg -x``, and its
directory on LD_LIBRARY_PATH). A reader that is not installed is said so.
"""

from __future__ import annotations

import io
import json
import os
import sys


def _openexr(data: bytes):
    import OpenEXR

    channels = OpenEXR.File(io.BytesIO(data)).channels()
    return {name: (tuple(c.pixels.shape), str(c.pixels.dtype)) for name, c in channels.items()}


def _imageio_default(path: str):
    import imageio.v3 as iio

    picture = iio.imread(path)
    return (picture.shape, str(picture.dtype))


def _imageio_freeimage(path: str):
    import imageio.v2 as iio2

    picture = iio2.imread(path, format="EXR-FI")
    return (picture.shape, str(picture.dtype))


def _pillow(path: str):
    from PIL import Image

    with Image.open(path) as image:
        return (image.size, image.mode)


def _skimage(path: str):
    from skimage import io as skio

    picture = skio.imread(path)
    return (picture.shape, str(picture.dtype))


READERS = {
    "OpenEXR (Python bindings)": lambda path, data: _openexr(data),
    "imageio v3 imread (default plugins)": lambda path, data: _imageio_default(path),
    "imageio v2 imread format=EXR-FI (FreeImage)": lambda path, data: _imageio_freeimage(path),
    "Pillow Image.open": lambda path, data: _pillow(path),
    "scikit-image io.imread": lambda path, data: _skimage(path),
}


def files(root: str) -> list[str]:
    with open(os.path.join(root, "manifest.jsonl"), encoding="utf-8") as fh:
        record = json.loads(fh.readline())
    roles = {f["role"]: f["path"] for f in record["files"]}
    return [os.path.join(root, roles[r]) for r in ("render", "maps", "texture") if r in roles]


def main(root: str) -> None:
    if os.environ.get("IMAGEIO_FREEIMAGE_LIB") is None:
        print("(IMAGEIO_FREEIMAGE_LIB not set: imageio's FreeImage plugin looks for its own download)")
    for name, read in READERS.items():
        for path in files(root):
            with open(path, "rb") as fh:
                data = fh.read()
            try:
                got = read(path, data)
                print(f"{name}: {os.path.basename(path)}: OK {got}")
            except ImportError as exc:
                print(f"{name}: not installed ({exc.name})")
                break
            except Exception as exc:  # a reader's own failure is the result
                message = " ".join(str(exc).split())[:240]
                print(f"{name}: {os.path.basename(path)}: FAILS {type(exc).__name__}: {message}")


if __name__ == "__main__":
    main(sys.argv[1])
