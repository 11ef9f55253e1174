"""The ranges and choices a render accepts, defined once: specs, commands, benchmarks and the CLI help use these."""

#: Mitsuba integrators a spec may name.
INTEGRATORS = ("path",)

#: Image width and height in pixels (square images).
RESOLUTION_RANGE = (16, 4096)
#: Samples per pixel.
SPP_RANGE = (1, 65536)
#: Path length (Mitsuba's ``max_depth``).
MAX_DEPTH_RANGE = (1, 64)


def span(bounds: tuple[int, int]) -> str:
    """``"16 to 4096"``: a range as the CLI help words it."""
    return f"{bounds[0]} to {bounds[1]}"
