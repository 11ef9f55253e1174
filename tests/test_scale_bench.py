"""`shaderball bench --scale`: its bad input, and a real run at two small sizes whose page,
figure and figures are checked."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner
from PIL import Image

REPO = Path(__file__).resolve().parents[1]


def _cli(*args):
    from cli import main

    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.mark.parametrize(
    "args, message",
    [
        (["--scale", "100"], "--scale: 100 is not allowed; 2 or more comma-separated integers from 2 to 10000000"),
        (["--scale", "100,100"], "--scale: 100,100 is not allowed; 2 or more comma-separated integers"),
        (["--scale", "1,100"], "--scale: 1,100 is not allowed; 2 or more comma-separated integers from 2 to"),
        (["--scale", "10,ten"], '--scale: "10,ten" is not allowed; 2 or more comma-separated integers'),
        (["--scale", "10,20", "--resolution", "8"], "--resolution: 8 is not allowed"),
        (["--scale", "5,20"], "--scale: 5 is not allowed; at least 10 renders with this spec"),
        (["--scale", "10,20", "--renders", "4"], "--renders: not an option of the scale benchmark"),
    ],
)
def test_scale_bad_input_exits_2_and_writes_nothing(tmp_path, args, message):
    out = tmp_path / "results"
    result = _cli("bench", *args, "--out", out)
    assert result.exit_code == 2 and message in result.output, result.output
    assert not out.exists()


def test_scale_needs_out():
    result = _cli("bench", "--scale", "10,20")
    assert result.exit_code == 2 and "--out: missing" in result.output, result.output


def test_scale_benchmark_writes_its_page_figure_and_figures(tmp_path):
    from pipeline.bench.scale import COMMANDS

    out = tmp_path / "scale"
    run = subprocess.run(
        [sys.executable, "-m", "cli", "bench", "--scale", "20,10", "--out", str(out)],
        cwd=REPO,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    # one summary line per command, with its slopes (the lead compares memory per render)
    for command in COMMANDS:
        assert any(line.startswith(command + " ") and "KB/render" in line for line in run.stdout.splitlines()), (
            command,
            run.stdout,
        )

    doc = json.loads((out / "scale.json").read_text())
    assert doc["sizes"] == [10, 20]  # sorted; the paper spec's 5 lightings: 2 and 4 materials
    assert doc["command"] == f"shaderball bench manifests/paper.toml --scale 10,20 --resolution 16 --spp 1 --out {out}"
    assert sorted((r["command"], r["renders"]) for r in doc["rows"]) == sorted(
        (c, n) for c in COMMANDS for n in (10, 20)
    )
    for row in doc["rows"]:
        # a Python process that imported the project: tens of MB at least, far from a leak; its time
        # only at least an import's (a busy machine makes it longer, without bound)
        assert 0.05 < row["wall_s"] < math.inf and 20 * 2**20 < row["peak_rss_bytes"] < 4 * 2**30, row
    assert set(doc["fits"]) == set(COMMANDS)
    for command, fit in doc["fits"].items():
        assert set(fit) == {"time_exponent", "memory_exponent", "seconds_per_render", "bytes_per_render"}
        assert all(math.isfinite(v) for v in fit.values()), (command, fit)
        # the exponent and the per-render cost agree in sign: both fitted to the same two points
        rows = sorted((r for r in doc["rows"] if r["command"] == command), key=lambda r: r["renders"])
        grew = rows[1]["peak_rss_bytes"] - rows[0]["peak_rss_bytes"]
        # a least-squares slope of values ~1e8 carries rounding far below a byte (0 can come out as 7e-10)
        assert fit["bytes_per_render"] == pytest.approx(grew / 10, abs=1e-3)
        assert math.copysign(1, fit["memory_exponent"]) == math.copysign(1, grew) or grew == 0

    page = (out / "README.md").read_text()
    assert page.startswith("# ") and f"Written by `{doc['command']}`" in page
    assert doc["machine"]["cpu_model"] in page and doc["date"] in page
    assert "![time and peak memory against size](scale.png)" in page
    for command in COMMANDS:
        assert sum(line.startswith(f"| {command} |") for line in page.splitlines()) == 2, command  # both tables

    # each command's peak at a million renders: the largest size's peak plus its (non-negative) cost beyond it
    for command, fit in doc["fits"].items():
        largest = max((r for r in doc["rows"] if r["command"] == command), key=lambda r: r["renders"])
        million = largest["peak_rss_bytes"] + max(fit["bytes_per_render"], 0) * (1_000_000 - largest["renders"])
        row = next(line for line in page.splitlines() if line.startswith(f"| {command} |") and line.endswith(" GB |"))
        assert row.rstrip(" |").endswith(f"{million / 2**30:.2f} GB"), (command, row)

    # the page and figure written again from scale.json alone (scripts/scale_page.py) are the same files
    written = {name: (out / name).read_bytes() for name in ("README.md", "scale.png")}
    for name in written:
        (out / name).unlink()
    again = subprocess.run(
        [sys.executable, "scripts/scale_page.py", str(out)], cwd=REPO, capture_output=True, text=True
    )
    assert again.returncode == 0, again.stderr
    assert {name: (out / name).read_bytes() for name in written} == written

    with Image.open(out / "scale.png") as figure:
        figure.load()
        assert figure.format == "PNG" and figure.size == (900, 1040)
        colours = figure.convert("RGB").getcolors(1 << 20)
    assert len(colours) > 10  # lines in several colours, not a blank page


def test_scale_page_refuses_a_folder_without_figures(tmp_path):
    done = subprocess.run(
        [sys.executable, "scripts/scale_page.py", str(tmp_path)], cwd=REPO, capture_output=True, text=True
    )
    assert done.returncode == 2 and "scale.json" in done.stderr and "nothing written" in done.stderr, done.stderr
    assert list(tmp_path.iterdir()) == []
