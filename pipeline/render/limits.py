"""The ranges and choices a render accepts, defined once: specs, commands, benchmarks and the CLI help use these."""

#: Mitsuba integrators a spec may name.
INTEGRATORS = ("path",)

#: Image width and height in pixels (square images).
RESOLUTION_RANGE = (16, 4096)
#: Samples per pixel.
SPP_RANGE = (1, 65536)
#: The most samples (pixels x spp) one ``mi.render`` call takes; a render over it is split into
#: launches (:func:`launch_spp`). Why: drjit indexes a launch's lanes in 32 bits, and above 2^32-1
#: Mitsuba 3.9 splits the render itself (integrator.cpp): it fails where spp is no multiple of
#: its pass ("sample_count should be a multiple of samples_per_wavefront": 4096 px at 65536 spp)
#: and otherwise keeps every lane's sampler state between its passes, measured 24-28 bytes a lane
#: (1024 px, its samples_per_pass 8 and 16; 4096 px at 256 spp: 48-56 GiB, a segfault at once under
#: a 6 GiB limit, as a build at 257 spp). One launch keeps none: 0 extra bytes a lane at 1024 px,
#: 16 spp; RSS flat at 0.88 GB over 85 s of a 2^31-lane launch at 4096 px; that build split: flat
#: at 1.3 GB (peak 2.3 GB) under the same limit (llvm, 2 cores).
LAUNCH_SAMPLES_MAX = 2**32 - 1
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


def launch_spp(spp: int, pixels: int, used=None) -> list[int]:
    """The spp of each ``mi.render`` call that renders ``spp`` on a film of ``pixels`` pixels:
    ``[spp]`` while ``pixels x used(spp)`` is at most :data:`LAUNCH_SAMPLES_MAX` (every render
    under the limit stays one call, as it always was), else launches of the largest power of
    two that fits and the remainder: 4096 px at 65536 spp -> 512 launches of 128. ``used(n)``:
    the spp a sampler really takes when asked for ``n`` (some round up); the identity if None."""
    used = used or (lambda n: n)
    spp, pixels = int(spp), int(pixels)
    if spp <= 0 or pixels * used(spp) <= LAUNCH_SAMPLES_MAX:
        return [spp]
    size = 1 << ((LAUNCH_SAMPLES_MAX // pixels).bit_length() - 1) if pixels <= LAUNCH_SAMPLES_MAX else 1
    while size > 1 and pixels * used(size) > LAUNCH_SAMPLES_MAX:
        size >>= 1
    whole, rest = divmod(spp, size)
    return [size] * whole + ([rest] if rest else [])


def launch_limit_text() -> str:
    """:data:`LAUNCH_SAMPLES_MAX` as the help words it: ``"2^32-1"``."""
    return span((0, LAUNCH_SAMPLES_MAX)).split(" to ")[1]
