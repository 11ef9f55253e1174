"""Where Mitsuba's RGB ``sunsky`` goes negative (pipeline.bench.sky_floor; docs/sky.md).

.venv/bin/python scripts/sky_floor.py            # the hard-case sweep table of docs/sky.md
.venv/bin/python scripts/sky_floor.py --table    # re-measure FLOOR_TABLE of sky/policy.py (slow)
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.bench.sky_floor import floor_table, floor_table_literal, sweep_markdown, sweep_rows  # noqa: E402
from pipeline.render.mitsuba_env import VARIANT_CHOICES, resolve_variant  # noqa: E402
from pipeline.render.sky_probe import SunskyProbe  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="scripts/sky_floor.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--table", action="store_true", help="measure the elevation floor table (slow)")
    parser.add_argument("--fine-step", type=float, default=0.05, help="turbidity step of the measurement")
    parser.add_argument("--variant", default="auto", choices=VARIANT_CHOICES, help="Mitsuba variant (default auto)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    probe = SunskyProbe(resolve_variant(args.variant))
    if args.table:
        rows, _ = floor_table(probe, fine_step=args.fine_step)
        print(floor_table_literal(rows))
    else:
        print(sweep_markdown(sweep_rows(probe)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
