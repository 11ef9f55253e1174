"""Write the two procedural environment maps (studio, outdoor) that manifests/scenes.toml and
`shaderball figures scenes` are lit by (pipeline.figures.environments says what they hold).

    .venv/bin/python scripts/make_environments.py                 # manifests/environments/
    .venv/bin/python scripts/make_environments.py --out DIR --height 256

Each map is OUT/<name>.exr, lat-long (width = 2 x height), half floats; written atomically.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def parse(argv: list[str]) -> argparse.Namespace:
    sys.path.insert(0, str(REPO))
    from pipeline.figures.environments import DEFAULT_HEIGHT, HEIGHT_RANGE, SHIPPED_FOLDER

    parser = argparse.ArgumentParser(prog="scripts/make_environments.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=str(REPO / SHIPPED_FOLDER), help="folder to write the maps into")
    parser.add_argument("--height", type=int, default=DEFAULT_HEIGHT, help="rows of each map (width: twice)")
    args = parser.parse_args(argv)
    low, high = HEIGHT_RANGE
    if not low <= args.height <= high:
        parser.error(f"--height: {args.height} is not allowed; an integer from {low} to {high}")
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        parser.error(f"--out: {args.out} exists and is not a folder")
    return args


def main(argv: list[str]) -> None:
    args = parse(argv)  # checked before anything is written
    from pipeline.figures.environments import write_environments

    for name, path in write_environments(args.out, args.height).items():
        print(f"wrote {path} ({name}, {2 * args.height}x{args.height}, {os.path.getsize(path)} bytes)")


if __name__ == "__main__":
    main(sys.argv[1:])
