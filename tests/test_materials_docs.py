"""The figures docs/materials.md shows are what their generators produce now: the albedo tables of
its results page (docs/results/albedo.md) and its contact sheet."""

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from pipeline.figures import albedo_table, contact_sheet

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "materials.md"
ALBEDO_PAGE = ROOT / "docs" / "results" / "albedo.md"
SHEET = ROOT / "docs" / "img" / "materials_contact_sheet.png"
SHEET_ARGS = dict(examples=4, resolution=128)  # what docs/materials.md says to run


@pytest.mark.slow  # ~5 s warm, ~9 s on a loaded 2-core machine (quadrature of 456 albedos)
def test_albedo_tables_in_docs_are_current():
    tables = albedo_table.markdown()
    page = ALBEDO_PAGE.read_text()
    assert page.startswith("# Directional albedo of the material model\n\nWritten by `")
    missing = [line for line in tables.splitlines() if line.strip() and line not in page]
    assert not missing, (
        f"{ALBEDO_PAGE} is out of date; re-run `.venv/bin/python scripts/albedo_results.py --write`. "
        f"First missing line: {missing[0]!r}"
    )
    assert "results/albedo.md" in DOC.read_text(), "docs/materials.md no longer links its albedo tables"


def test_albedo_lut_numbers():
    lut = albedo_table.build_lut(roughness=(0.05, 0.5, 1.0), incidence_deg=(0.0, 85.0))
    # F = 1 smooth at normal incidence keeps everything; s = 0 is the Schlick grazing term only.
    assert lut.a1[0, 0] == pytest.approx(1.0, abs=2e-3)
    assert lut.a0[0, 0] < 1e-3 and lut.a0[0, 1] > 0.5
    # total for d = 1, s = 0 exceeds 1 at grazing incidence: the model's 1 - s ignores Fresnel
    total = lut.total(np.array([[1.0, 1.0, 1.0]]), np.array([[0.0, 0.0, 0.0]]), np.array([0.05]), 1)
    assert total.max() > 1.5


def test_model_comparison_numbers():
    # A1 at normal incidence 0.012 / 0.19 / 0.76 with Deschaintre et al.'s floors, ~1 without.
    a1 = albedo_table.model_comparison(roughness=(0.05, 0.1, 0.15, 0.2))
    np.testing.assert_allclose(a1["shaderball"], 1.0, atol=3e-3)
    np.testing.assert_allclose(a1["deschaintre2018"][:3], [0.012, 0.190, 0.755], atol=2e-3)
    assert a1["deschaintre2018"][3] == pytest.approx(a1["shaderball"][3], rel=1e-12)  # summation order only
    assert albedo_table.FLOOR_ROUGHNESS == pytest.approx(0.1778, abs=1e-4)


def test_figures_defaults_are_the_requests_and_another_figures_option_is_refused(tmp_path, monkeypatch):
    from click.testing import CliRunner

    import cli
    from pipeline.figures.command import FiguresRequest

    sheet = FiguresRequest(name="contact-sheet", out="x.png")
    assert (sheet.examples, sheet.resolution, sheet.seed) == (4, 128, contact_sheet.SHEET_SEED)
    assert {"examples": sheet.examples, "resolution": sheet.resolution} == SHEET_ARGS  # what the docs run
    monkeypatch.chdir(tmp_path)
    for args, message in (
        (["sun-positions", "--out", "s.png", "--examples", "2"], "--examples: not an option of sun-positions; "),
        (["albedo-table", "--resolution", "64"], "--resolution: not an option of albedo-table; albedo-table takes "),
        (["contact-sheet", "--out", "s.png", "--no-samplers"], "--no-samplers: not an option of contact-sheet"),
        (["contact-sheet"], "--out: missing; a PNG file for contact-sheet"),
        (["contact-sheet", "--out", "s.png", "--examples", "65"], "--examples: 65 is not allowed; an integer from 1"),
    ):
        result = CliRunner().invoke(cli.main, ["figures", *args])
        assert result.exit_code == 2 and message in result.output, (args, result.output)
    assert not list(tmp_path.iterdir()), "nothing is written"


def test_contact_sheet_is_reproducible_and_current():
    small = contact_sheet.contact_sheet(examples=1, resolution=32)
    assert small.dtype == np.uint8 and small.ndim == 3
    assert np.array_equal(small, contact_sheet.contact_sheet(examples=1, resolution=32))
    current = contact_sheet.contact_sheet(**SHEET_ARGS)
    stored = np.asarray(Image.open(SHEET).convert("RGB"))
    assert np.array_equal(current, stored), (
        f"{SHEET} is out of date; re-run `shaderball figures contact-sheet --out {SHEET.relative_to(ROOT)} "
        "--examples 4`"
    )
