"""What the neural stage does to a dataset before its first step, as one process to measure
(pipeline.neural.open_probe); the scale benchmark runs it as a child process.

    .venv/bin/python scripts/open_probe.py loader DATASET
    .venv/bin/python scripts/open_probe.py evaluate-setup DATASET

Prints one JSON line (samples, seconds).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.errors import USER_ERRORS  # noqa: E402
from pipeline.neural.open_probe import PROBES, run_probe  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="scripts/open_probe.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("probe", choices=PROBES)
    parser.add_argument("dataset", help="a dataset folder or its publication")
    args = parser.parse_args(argv)
    try:
        result = run_probe(args.probe, args.dataset)
    except USER_ERRORS as exc:
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
