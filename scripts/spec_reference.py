"""Write docs/spec-fields.md: every spec field's meaning, unit, default and what is allowed,
from the spec's typed fields (``pipeline.dataset.spec_file.reference_markdown``).

    .venv/bin/python scripts/spec_reference.py           # print the page
    .venv/bin/python scripts/spec_reference.py --write   # replace docs/spec-fields.md

tests/test_spec.py fails when the page is not what the code generates.
"""

from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PAGE = REPO / "docs" / "spec-fields.md"
WRITE_COMMAND = ".venv/bin/python scripts/spec_reference.py --write"


def render() -> str:
    sys.path.insert(0, str(REPO))
    from pipeline.dataset.spec_file import reference_markdown

    return (
        "# Spec field reference\n\n"
        f"Written by `{WRITE_COMMAND}` from the spec's typed fields; do not edit by hand\n"
        "(`tests/test_spec.py` fails when it is stale). What a spec is, its rules and its plan:\n"
        '[spec.md](spec.md). Units: "-" means dimensionless. Angles are in degrees in the world\n'
        "frame of [conventions.md](conventions.md) (z up; azimuth counter-clockwise from +x seen from above).\n\n"
        + reference_markdown().rstrip("\n")
        + "\n"
    )


if __name__ == "__main__":
    sys.path.insert(0, str(REPO))
    from scripts.results_page import write_flag

    write = write_flag(sys.argv[1:], "spec_reference.py")  # checked before anything is written
    text = render()
    if write:
        PAGE.write_text(text, encoding="utf-8")
        print(f"wrote {PAGE.relative_to(REPO)}")
    else:
        print(text, end="")
