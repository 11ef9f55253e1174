"""Write a scale benchmark's page and figure again from its figures, without measuring anything:

    .venv/bin/python scripts/scale_page.py docs/results/scale

Reads DIR/scale.json (written by `shaderball bench --scale ... --out DIR`) and writes DIR/README.md,
DIR/scale.png and DIR/scale.json again with the same code the benchmark uses: for a change of the
page's layout or of what it derives from the figures (fits, extrapolations), not of the figures.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from pipeline.bench.scale import ScaleBench, write_results  # noqa: E402


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python scripts/scale_page.py DIR (a folder holding scale.json)", file=sys.stderr)
        return 2
    folder = Path(argv[0])
    try:
        bench = ScaleBench.from_dict(json.loads((folder / "scale.json").read_text()))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        print(
            f"error: {folder / 'scale.json'}: not a scale benchmark's figures ({exc}); nothing written", file=sys.stderr
        )
        return 2
    write_results(bench, str(folder))
    print(f"wrote {folder / 'README.md'} and {folder / 'scale.png'} from {folder / 'scale.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
