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
    """``"16 to 4096"``: a range of integers as the CLI help words it; a top of 2^k-1 (a seed's)
    as ``"2^32-1"``."""
    low, high = bounds
    top = f"2^{high.bit_length()}-1" if high >= 2**16 - 1 and high & (high + 1) == 0 else str(high)
    return f"{low} to {top}"


def interval(bounds: tuple[float, float]) -> str:
    """``"[0, 90]"``: a closed range of numbers as the CLI help words it."""
    return f"[{bounds[0]:g}, {bounds[1]:g}]"


#: Mitsuba samplers a spec may name. Mitsuba rounds some sample counts (stratified: a square,
#: multijitter: a product of two near-equal factors, orthogonal: a prime squared, ldsampler:
#: a power-of-two square); renders record the spp actually used.
SAMPLERS = ("independent", "stratified", "multijitter", "orthogonal", "ldsampler")
#: Depth at which Russian roulette starts (Mitsuba's ``rr_depth``; its default 5).
RR_DEPTH_RANGE = (1, 64)
DEFAULT_RR_DEPTH = 5
#: Luminance clamp of each camera path's contribution (0: off); radiance units.
CLAMP_RANGE = (0.0, 1.0e6)
#: Adaptive rendering's target: relative RMS standard error on the ball (0: off).
TARGET_ERROR_RANGE = (0.0, 1.0)
