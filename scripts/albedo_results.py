"""Write docs/results/albedo.md: the directional-albedo tables of the material model, which
docs/materials.md quotes (``pipeline.figures.albedo_table``; about 10 s).

    .venv/bin/python scripts/albedo_results.py            # print the page
    .venv/bin/python scripts/albedo_results.py --write    # write docs/results/albedo.md

tests/test_materials_docs.py fails when the page's tables are not what the code computes now.
"""

from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from pipeline.figures import albedo_table  # noqa: E402
from scripts.results_page import head, write_flag  # noqa: E402

PAGE = REPO / "docs" / "results" / "albedo.md"

ABOUT = (
    "Directional albedo `a(wi) = int f(wi, wo) cos(theta_o) dwo` (the white-furnace value) of the "
    "Cook-Torrance model of docs/materials.md, by deterministic quadrature with the numpy reference "
    "(error about 1e-3). Per channel `a = d (1 - s) + s A1 + (1 - s) A0`: `A1` is the specular albedo "
    "with F = 1, `A0` the one with s = 0 (Schlick's grazing term). Rows: roughness r (alpha = r^2); "
    "columns: incidence angle. Last, the `deschaintre2018` model, whose floors lose light below "
    "r = 0.178, beside the default.\n\n"
)


def page_text() -> str:
    return head("Directional albedo of the material model", ".venv/bin/python scripts/albedo_results.py --write") + (
        ABOUT + albedo_table.markdown() + "\n"
    )


if __name__ == "__main__":
    write = write_flag(sys.argv[1:], "albedo_results.py")  # checked before anything runs or is written
    text = page_text()
    if write:
        PAGE.parent.mkdir(parents=True, exist_ok=True)
        PAGE.write_text(text)
    else:
        print(text, end="")
