"""The one reader of image files from outside (SVBRDF map files, a publication's previews):
the image's size is read from its header and checked before any pixel is decoded.

Pillow opens a file lazily: ``Image.open`` reads the header (size, mode) and ``load`` decodes
the pixels. Between the two, the size is checked against what the caller expects, so a
500 kB PNG of 13000 x 13000 pixels costs nothing but its header. Pillow's own limit
(``Image.MAX_IMAGE_PIXELS``, past which it warns, and past twice which it raises
``DecompressionBombError``) is set here explicitly rather than left to its default, and both
its warning and its error become :class:`~materials.errors.MaterialError` naming the file.
The pixels come back as stored (8 or 16 bits), never as float64: a caller converts what it
keeps, after cropping.
"""

from __future__ import annotations

import io
import os
import warnings

import numpy as np

from materials.errors import MaterialError

#: Pillow's limit on the pixels of any image opened (a strip of five 2048 x 2048 panels).
MAX_IMAGE_PIXELS = 5 * 2048 * 2048
#: Modes read, and the value of full scale in each: 8-bit, 16-bit (and 32-bit integer,
#: which Pillow gives some 16-bit files) grey and colour, palette images as RGB.
FULL_SCALE = {"L": 255.0, "LA": 255.0, "RGB": 255.0, "RGBA": 255.0, "I;16": 65535.0, "I;16B": 65535.0}
FULL_SCALE |= {"I;16L": 65535.0, "I": 65535.0}


def read_image(
    source: str | os.PathLike | bytes, label: str, max_width: int, max_height: int
) -> tuple[np.ndarray, float]:
    """The pixels of the image at ``source`` (a path, or the file's bytes) as stored, (H, W)
    or (H, W, C) uint8/uint16/int32, and the value of full scale (255 or 65535); a palette
    image comes as RGB. Refused with :class:`MaterialError` naming ``label`` when the header
    says it is over ``max_width`` x ``max_height`` pixels, before anything is decoded, or when
    it cannot be read."""
    from PIL import Image

    Image.MAX_IMAGE_PIXELS = MAX_IMAGE_PIXELS
    opened = io.BytesIO(source) if isinstance(source, bytes) else source
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(opened) as image:
                width, height = image.size
                if width > max_width or height > max_height:
                    raise MaterialError(
                        f"{label}: the image is {width} x {height} pixels; at most {max_width} x "
                        f"{max_height} are read (its header was read, no pixel decoded)"
                    )
                if image.mode not in FULL_SCALE and image.mode != "P":
                    raise MaterialError(f"{label}: image mode {image.mode!r} is not supported (8/16-bit grey or RGB)")
                image.load()
                if image.mode == "P":
                    return np.asarray(image.convert("RGB")), 255.0
                return np.asarray(image), FULL_SCALE[image.mode]
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise MaterialError(f"{label}: refused by Pillow's pixel limit ({exc})") from None
    except (OSError, ValueError, SyntaxError) as exc:
        if isinstance(exc, MaterialError):
            raise
        raise MaterialError(f"{label}: cannot read image: {exc}") from exc
