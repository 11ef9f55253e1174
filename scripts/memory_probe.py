"""How a render worker's resident memory grows over many renders (pipeline.bench.memory_probe;
docs/cluster.md).

    .venv/bin/python scripts/memory_probe.py --memory-probe 200 --resolution 400 --spp 16

Renders N samples in one process, shard after shard; prints RSS as it goes and a summary.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.bench.memory_probe import MAX_PROBE_RENDERS, memory_probe  # noqa: E402
from pipeline.errors import USER_ERRORS  # noqa: E402
from pipeline.fields import FieldError  # noqa: E402
from pipeline.render.limits import RESOLUTION_RANGE, span  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="scripts/memory_probe.py", description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--memory-probe",
        type=int,
        metavar="N",
        required=True,
        help=f"renders to run in one process (2 per material), 2 to {MAX_PROBE_RENDERS}",
    )
    parser.add_argument("--resolution", type=int, default=64, help=f"pixels, {span(RESOLUTION_RANGE)} (default 64)")
    parser.add_argument("--spp", type=int, default=16, help="samples per pixel (default 16)")
    parser.add_argument("--every", type=int, default=20, help="print RSS every N renders (default 20)")
    args = parser.parse_args(argv)

    def show(done: int, rss: float) -> None:
        if done % max(1, args.every) < 2:
            print(f"{done:6d} renders  RSS {rss:8.1f} MiB", flush=True)

    try:
        result = memory_probe(args.memory_probe, args.resolution, args.spp, progress=show)
    except USER_ERRORS as exc:
        if isinstance(exc, FieldError):  # a field of ProbeRequest, as this script spells it
            exc = exc.labelled(lambda name: "--memory-probe" if name == "renders" else "--" + name)
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code
    for line in result.lines():
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
