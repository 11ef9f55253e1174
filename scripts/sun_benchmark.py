"""Sun inside ``sunsky`` vs the split (directional sun + sky-only ``sunsky``): noise, bias,
time (pipeline.bench.sun_benchmark; docs/sky.md). About three minutes on 2 cores.

    .venv/bin/python scripts/sun_benchmark.py [--sun-weight-factor 5] [--skip-time]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import sky.emitter as sky_emitter  # noqa: E402
from pipeline.bench.sun_benchmark import format_noise, format_time, noise_table, time_table  # noqa: E402
from pipeline.render.mitsuba_env import VARIANT_CHOICES, load_mitsuba, resolve_variant  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="scripts/sun_benchmark.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--resolution", type=int, default=64, help="noise table image size")
    parser.add_argument("--spp", type=int, nargs="+", default=[16, 150], help="noise table spp levels")
    parser.add_argument("--ref-spp", type=int, default=2048)
    parser.add_argument("--time-resolution", type=int, default=256)
    parser.add_argument("--time-spp", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=3, help="timed renders per point (median)")
    parser.add_argument("--sun-weight-factor", type=float, default=sky_emitter.SPLIT_SUN_WEIGHT_FACTOR)
    parser.add_argument("--sun-weight-exponent", type=float, default=sky_emitter.SPLIT_SUN_WEIGHT_EXPONENT)
    parser.add_argument("--variant", default="auto", choices=VARIANT_CHOICES, help="Mitsuba variant (default auto)")
    parser.add_argument("--skip-time", action="store_true")
    args = parser.parse_args(argv)

    mi = load_mitsuba(resolve_variant(args.variant))
    # the rule tried for the split's emitter sampling weights (pipeline.render.emitter.split_sampling_weights)
    sky_emitter.SPLIT_SUN_WEIGHT_FACTOR = args.sun_weight_factor
    sky_emitter.SPLIT_SUN_WEIGHT_EXPONENT = args.sun_weight_exponent
    print(f"split sun weight = {args.sun_weight_factor:g} x (sun / sky)^{args.sun_weight_exponent:g}\n")
    print(format_noise(noise_table(mi, args.resolution, tuple(args.spp), args.ref_spp)))
    if not args.skip_time:
        rows = time_table(mi, args.time_resolution, args.time_spp, args.repeats)
        print()
        print(format_time(rows, args.time_resolution, args.time_spp))
    return 0


if __name__ == "__main__":
    sys.exit(main())
