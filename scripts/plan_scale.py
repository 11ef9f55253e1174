"""How a spec of millions of renders plans and starts building (pipeline.bench.plan_scale):
a measurement, printed, not a timed test.

    .venv/bin/python scripts/plan_scale.py [--materials 1000000] [--lights 10] [--shard-size 20]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.bench.plan_scale import measure_plan_scale, plan_scale_lines  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="scripts/plan_scale.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--materials", type=int, default=1_000_000)
    parser.add_argument("--lights", type=int, default=10)
    parser.add_argument("--shard-size", type=int, default=20)
    args = parser.parse_args(argv)
    for line in plan_scale_lines(measure_plan_scale(args.materials, args.lights, args.shard_size)):
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
