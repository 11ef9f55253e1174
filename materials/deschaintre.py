"""Importer for SVBRDF files in Deschaintre et al. 2018's layout.

Two layouts are read:

* **strip**: one PNG of five equal-width panels, left to right: input photo,
  normal, diffuse, roughness, specular (288 x 288 panels in their release,
  so 1440 x 288). The photo is ignored.
* **folder**: separate images of the four maps in one directory, each found
  by its stem: ``normal``, ``diffuse``, ``roughness``, ``specular``, alone
  or after a prefix and ``_``/``-``/``.`` (``0042_diffuse.png``). Extensions
  png, jpg/jpeg, tif/tiff, bmp.

Values: 8-bit or 16-bit images are scaled to [0, 1]. Their code feeds the
stored values to the BRDF without gamma decoding (it maps [0, 1] to [-1, 1]
for the network and back), so the default colour space of every map is
``"raw"``: the stored value is the linear albedo / roughness. ``"srgb"``
decodes the sRGB transfer function with colour-science instead; it may be
chosen per map (``colorspace={"diffuse": "srgb"}``) or for the albedos at
once (``colorspace="srgb"`` applies to diffuse and specular; roughness stays
raw unless named). Normals are always raw: ``n = 2 c - 1``, renormalised,
in the frame of :mod:`materials.maps` (x right, y up the picture), which is
their renderer's frame, so no channel is flipped. The roughness panel is
stored as grey RGB; its channels are averaged.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from materials.colorspace import COLORSPACES, srgb_decode
from materials.errors import MaterialError
from materials.imagefile import read_image
from materials.maps import MaterialMaps, decode_normal_map

log = logging.getLogger(__name__)

#: Panel order of a strip, left to right.
STRIP_PANELS = ("photo", "normal", "diffuse", "roughness", "specular")
#: Maps read from a folder, in MaterialMaps order.
MAP_NAMES = ("diffuse", "specular", "roughness", "normal")
#: Maps whose colour space can be chosen (normals are data, always raw).
COLOUR_MAPS = ("diffuse", "specular", "roughness")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
#: Largest map read, in pixels a side (their release: 288; the largest texture_resolution
#: a spec may ask of a procedural map is 4096). A strip is at most five such panels wide.
MAX_MAP_SIDE = 2048
#: Default: matches their renderer, which takes the stored values as linear.
DEFAULT_COLORSPACE = "raw"


def resolve_colorspaces(colorspace: str | Mapping[str, str] = DEFAULT_COLORSPACE) -> dict[str, str]:
    """Per-map colour spaces from the ``colorspace`` argument (see module docstring)."""
    result = dict.fromkeys(COLOUR_MAPS, DEFAULT_COLORSPACE)
    if isinstance(colorspace, str):
        if colorspace not in COLORSPACES:
            raise MaterialError(f"colorspace: {colorspace!r} is not one of {', '.join(COLORSPACES)}")
        result["diffuse"] = result["specular"] = colorspace
        return result
    if not isinstance(colorspace, Mapping):
        raise MaterialError(f"colorspace: {colorspace!r} is not a string or a mapping of map name to colour space")
    for name, space in colorspace.items():
        if name == "normal":
            if space != "raw":
                raise MaterialError(f"colorspace.normal: {space!r} is not allowed; normals are always 'raw'")
            continue
        if name not in COLOUR_MAPS:
            raise MaterialError(f"colorspace: map {name!r} is not one of {', '.join(COLOUR_MAPS + ('normal',))}")
        if space not in COLORSPACES:
            raise MaterialError(f"colorspace.{name}: {space!r} is not one of {', '.join(COLORSPACES)}")
        result[name] = space
    return result


def load_deschaintre(path, colorspace: str | Mapping[str, str] = DEFAULT_COLORSPACE) -> MaterialMaps:
    """Read a strip PNG or a folder of maps (module docstring) into :class:`MaterialMaps`."""
    spaces = resolve_colorspaces(colorspace)
    path = Path(path)
    if path.is_dir():
        images = {
            name: _scaled(*_read_image(file, MAX_MAP_SIDE, MAX_MAP_SIDE)) for name, file in _find_maps(path).items()
        }
        sizes = {name: image.shape[:2] for name, image in images.items()}
        if len(set(sizes.values())) != 1:
            raise MaterialError(f"{path}: maps differ in size (height, width): {sizes}")
        source = str(path)
    elif path.is_file():
        images = _split_strip(path, _read_image(path, len(STRIP_PANELS) * MAX_MAP_SIDE, MAX_MAP_SIDE))
        source = str(path)
    else:
        raise MaterialError(f"SVBRDF path {str(path)!r} is neither a file nor a directory")
    return _to_maps(images, spaces, source)


def _find_maps(folder: Path) -> dict[str, Path]:
    files = [p for p in sorted(folder.iterdir()) if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES]
    found: dict[str, Path] = {}
    for name in MAP_NAMES:
        matches = [p for p in files if _stem_matches(p.stem.lower(), name)]
        if not matches:
            raise MaterialError(
                f"{folder}: no {name} map; expected a file named {name}.png (or PREFIX_{name}.png, "
                f"extensions {', '.join(IMAGE_SUFFIXES)})"
            )
        if len(matches) > 1:
            raise MaterialError(f"{folder}: several {name} maps: {', '.join(p.name for p in matches)}")
        found[name] = matches[0]
    return found


def _stem_matches(stem: str, name: str) -> bool:
    return stem == name or any(stem.endswith(sep + name) for sep in ("_", "-", "."))


def _read_image(path: Path, max_width: int, max_height: int) -> tuple[np.ndarray, float]:
    """(H, W, C) pixels as stored, alpha dropped, and their full scale; the size is checked
    from the header before anything is decoded (materials.imagefile)."""
    array, full_scale = read_image(path, str(path), max_width, max_height)
    if array.ndim == 2:
        array = array[..., None]
    if array.shape[-1] in (2, 4):  # drop alpha
        array = array[..., :-1]
    return array, full_scale


def _scaled(array: np.ndarray, full_scale: float) -> np.ndarray:
    """float64 in [0, 1]: converted per map, after a strip is cut, so the photo never is."""
    return np.asarray(array, dtype=np.float64) / full_scale


def _split_strip(path: Path, image: tuple[np.ndarray, float]) -> dict[str, np.ndarray]:
    array, full_scale = image
    height, width = array.shape[:2]
    count = len(STRIP_PANELS)
    if width % count != 0 or width == 0:
        raise MaterialError(
            f"{path}: width {width} is not a multiple of {count}; expected {count} equal panels "
            f"({', '.join(STRIP_PANELS)}), e.g. 1440 x 288"
        )
    panel = width // count
    return {
        name: _scaled(array[:, k * panel : (k + 1) * panel], full_scale)
        for k, name in enumerate(STRIP_PANELS)
        if name != "photo"
    }


def _rgb(name: str, image: np.ndarray, source: str) -> np.ndarray:
    if image.shape[-1] == 1:
        return np.repeat(image, 3, axis=-1)
    if image.shape[-1] != 3:
        raise MaterialError(f"{source}: {name} map has {image.shape[-1]} channels; expected 1 or 3")
    return image


def _to_maps(images: dict[str, np.ndarray], spaces: dict[str, str], source: str) -> MaterialMaps:
    def decode(name: str, values: np.ndarray) -> np.ndarray:
        return srgb_decode(values) if spaces[name] == "srgb" else values

    diffuse = decode("diffuse", _rgb("diffuse", images["diffuse"], source))
    specular = decode("specular", _rgb("specular", images["specular"], source))
    roughness_rgb = images["roughness"]
    if roughness_rgb.shape[-1] > 1 and np.ptp(roughness_rgb, axis=-1).max() > 2.0 / 255.0:
        log.warning(
            "%s: roughness channels differ (up to %.3f); using their mean",
            source,
            float(np.ptp(roughness_rgb, axis=-1).max()),
        )
    roughness = decode("roughness", roughness_rgb.mean(axis=-1))
    normal, repaired = decode_normal_map(_rgb("normal", images["normal"], source))
    if repaired:
        log.warning("%s: %d normal texels were zero-length or at/below the tangent plane; repaired", source, repaired)
    return MaterialMaps(
        diffuse=np.clip(diffuse, 0.0, 1.0),
        specular=np.clip(specular, 0.0, 1.0),
        roughness=np.clip(roughness, 0.0, 1.0),
        normal=normal,
    ).check()
