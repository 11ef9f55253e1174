"""An untrusted EXR member's header checked without OpenEXR (pipeline.store.exrheader), so
that nothing decodes a file whose header would make the decoder allocate absurdly (a 2e9 x
2e9 data window, 4096 x 4096 x 64 channels for a 64 x 64 render), or that is not the kind of
file a dataset holds (tiled, deep, multi-part): refused as ``exr_header``."""

from __future__ import annotations

from dataclasses import replace

import tomllib

from pipeline.dataset.spec import RESOLUTION_RANGE
from pipeline.dataset.spec_file import MAX_SPEC_BYTES
from pipeline.publish.refusal import Limits, Refused
from pipeline.store.exr import ROLE_LAYERS, layer_bounds
from pipeline.store.exrheader import DEFAULT_BOUNDS, ExrBounds, ExrRefused, check_header


def check_exr_header(
    data: bytes, label: str, limits: Limits, bounds: ExrBounds = DEFAULT_BOUNDS
) -> tuple[int, int, list[str]]:
    """(width, height, channel names) of a single-part scanline EXR within ``bounds`` (what
    the manifest expects of it) and ``limits``' caps, or :class:`Refused`."""
    bounds = replace(bounds, max_side=limits.exr_side, header_bytes=limits.exr_header_bytes)
    try:
        header = check_header(data, label, bounds)
    except ExrRefused as exc:
        raise Refused("exr_header", f"{exc}; refused") from None
    return header.width, header.height, list(header.channels)


def member_bounds(spec: bytes) -> dict[str, ExrBounds]:
    """What each role's EXR members may hold, from the published spec (its bytes; checked
    as a spec only by unpack's validation): renders and maps at ``[render] resolution``,
    textures at ``[materials] texture_resolution`` unless maps are imported (their files keep
    their own size). A spec that does not say leaves only the budget (DEFAULT_BOUNDS)."""
    try:
        table = tomllib.loads(spec.decode("utf-8-sig")) if len(spec) <= MAX_SPEC_BYTES else {}
    except (UnicodeDecodeError, tomllib.TOMLDecodeError, RecursionError):
        table = {}

    def side(section: str, key: str, bounds: tuple[int, int]) -> int | None:
        value = table.get(section, {}).get(key) if isinstance(table.get(section), dict) else None
        ok = isinstance(value, int) and not isinstance(value, bool) and bounds[0] <= value <= bounds[1]
        return value if ok else None

    resolution = side("render", "resolution", RESOLUTION_RANGE)
    texture = side("materials", "texture_resolution", RESOLUTION_RANGE)
    materials = table.get("materials") if isinstance(table.get("materials"), dict) else {}
    if materials.get("svbrdf_folders") != []:
        texture = None
    sides = {"render": resolution, "maps": resolution, "texture": texture}
    return {role: layer_bounds(sides[role], layers) for role, layers in ROLE_LAYERS.items()}
