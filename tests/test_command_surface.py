"""One command surface: the library parses no arguments and prints nothing (every entry point
is a `shaderball` command or a script in scripts/), and the commands over finished work
(export, sweep, figures, neural-bench) run for real on the smoke dataset."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from cli import main

REPO = Path(__file__).resolve().parents[1]
LIBRARY = ("pipeline", "materials", "sky", "geometry")
NEW_COMMANDS = (
    ("export",),
    ("sweep",),
    ("figures",),
    ("neural-bench",),
    ("neural-bench", "loaders"),
    ("neural-bench", "collate"),
    ("neural-bench", "denoise"),
    ("neural-bench", "train-options"),
)
SCRIPTS = ("cross_cpu", "memory_probe", "open_probe", "plan_scale", "sky_floor", "sun_benchmark")
TRAIN = ["--epochs", "1", "--loss", "l1", "--width", "0.25", "--batch-size", "4", "--threads", "1", "--seed", "0"]


def _library_files() -> list[Path]:
    return sorted(p for package in LIBRARY for p in (REPO / package).rglob("*.py"))


def _is_main_guard(node: ast.AST) -> bool:
    """``if __name__ == "__main__":`` (either operand order)."""
    if not isinstance(node, ast.If) or not isinstance(node.test, ast.Compare):
        return False
    operands = [node.test.left, *node.test.comparators]
    names = {o.id for o in operands if isinstance(o, ast.Name)}
    strings = {o.value for o in operands if isinstance(o, ast.Constant)}
    return "__name__" in names and "__main__" in strings


def _offences(path: Path, root: Path = REPO) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    where = path.relative_to(root)
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import) and any(a.name.split(".")[0] == "argparse" for a in node.names):
            found.append(f"{where}:{node.lineno} imports argparse")
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "argparse":
            found.append(f"{where}:{node.lineno} imports from argparse")
        elif _is_main_guard(node):
            found.append(f"{where}:{node.lineno} has an `if __name__ == '__main__'` entry point")
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print":
            found.append(f"{where}:{node.lineno} calls print(")
    return found


def test_the_library_parses_no_arguments_has_no_entry_points_and_never_prints():
    files = _library_files()
    assert len(files) > 100  # the walk sees the packages
    offences = [o for path in files for o in _offences(path)]
    offences += [f"{p.relative_to(REPO)} is an entry point" for p in files if p.name == "__main__.py"]
    assert not offences, "\n".join(offences) + "\n(a command belongs in cli.py, a measurement tool in scripts/)"


def test_the_walk_finds_each_kind_of_offence(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text(
        "import argparse\nfrom argparse import ArgumentParser\n\n\ndef f():\n    print('x')\n\n\n"
        "if '__main__' == __name__:\n    f()\n"
    )
    found = sorted(_offences(bad, tmp_path))
    assert found == [
        "bad.py:1 imports argparse",
        "bad.py:2 imports from argparse",
        "bad.py:6 calls print(",
        "bad.py:9 has an `if __name__ == '__main__'` entry point",
    ]
    clean = tmp_path / "clean.py"
    clean.write_text("import logging\n\nlog = logging.getLogger(__name__)\ntext = 'print(1)'\n")
    assert _offences(clean, tmp_path) == []


@pytest.mark.parametrize("command", NEW_COMMANDS, ids=" ".join)
def test_each_new_command_has_help_ending_with_an_example(command):
    result = CliRunner().invoke(main, [*command, "--help"])
    assert result.exit_code == 0, result.output
    assert "Example:" in result.output
    example = result.output.split("Example:", 1)[1].split("Options:", 1)[0].strip().splitlines()[0].strip()
    assert example.startswith("shaderball " + " ".join(command)), example


@pytest.mark.parametrize("script", SCRIPTS)
def test_each_measurement_script_answers_help(script):
    done = subprocess.run(
        [sys.executable, str(REPO / "scripts" / f"{script}.py"), "--help"], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"usage: scripts/{script}.py")


def _cli(*args, cwd=REPO):
    return subprocess.run(
        [sys.executable, "-m", "cli", *map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=600
    )


@pytest.fixture(scope="module")
def run(reference, tmp_path_factory):
    """A 1-epoch run of a quarter-width network on the smoke dataset."""
    out = tmp_path_factory.mktemp("surface") / "run"
    result = CliRunner().invoke(main, ["train", str(reference), "--out", str(out), *TRAIN])
    assert result.exit_code == 0, result.output
    return out


@pytest.mark.slow
def test_export_writes_torchscript_that_torch_loads_and_says_one_line(run, tmp_path):
    import torch

    out = tmp_path / "net.pt"
    done = _cli("export", run, "--out", out)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == f"wrote {out}: TorchScript, 64x64, last checkpoint"
    assert "Warning" not in done.stderr and "Traceback" not in done.stderr, done.stderr
    net = torch.jit.load(str(out))
    assert tuple(net(torch.rand(1, 12, 64, 64), torch.tensor([[0.0, 0.0, 3.0, 3.0]])).shape) == (1, 3, 64, 64)
    as_json = _cli("export", run, "--out", tmp_path / "best.pt", "--checkpoint", "best", "--json")
    assert as_json.returncode == 0, as_json.stderr
    doc = json.loads(as_json.stdout)
    assert doc["checkpoint"] == "best" and doc["resolution"] == 64 and doc["out"] == str(tmp_path / "best.pt")
    refused = _cli("export", run, "--out", tmp_path / "net.onnx")
    assert refused.returncode == 2 and "error: --out" in refused.stderr
    assert not (tmp_path / "net.onnx").exists()


@pytest.mark.slow
def test_sweep_of_a_real_evaluation_report(run, reference, tmp_path):
    evaluation = tmp_path / "evaluation"
    evaluated = _cli(
        "evaluate", run, reference, "--limit", 2, "--no-flip", "--no-denoise", "--report", "--out", evaluation
    )
    assert evaluated.returncode == 0, evaluated.stderr
    out = tmp_path / "sweep"
    done = _cli("sweep", evaluation / "report.json", "--out", out, "--json")
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary.pop("ok") is True and summary.pop("exit") == 0  # --json's, beside what sweep.json holds
    assert summary == json.loads((out / "sweep.json").read_text())
    assert [r["seed"] for r in summary["runs"]] == [0] and (out / "data-size.png").stat().st_size > 0
    # headed by the command that wrote it, spelled from the request
    heading = f"Written by `shaderball sweep {evaluation / 'report.json'} --out {out}` on "
    assert (out / "sweep.md").read_text().splitlines()[2].startswith(heading)
    refused = _cli("sweep", run / "config.json", "--out", tmp_path / "other")
    assert refused.returncode == 2 and "report.json" in refused.stderr
    assert not (tmp_path / "other").exists()


def test_figures_contact_sheet_at_a_tiny_size(tmp_path):
    from PIL import Image

    out = tmp_path / "figures" / "sheet.png"
    done = _cli("figures", "contact-sheet", "--out", out, "--examples", 1, "--resolution", 16, "--json")
    assert done.returncode == 0, done.stderr
    doc = json.loads(done.stdout)
    assert Image.open(out).size == (doc["width"], doc["height"]) and doc["figure"] == "contact-sheet"
    assert "family 6/6" in done.stderr  # progress, on stderr
    for args, option in (
        (("sun-positions",), "--out"),
        (("contact-sheet", "--out", tmp_path / "x.png", "--models"), "--models"),
        (("contact-sheet", "--out", tmp_path / "x.png", "--resolution", 4), "--resolution"),
    ):
        refused = _cli("figures", *args)
        assert refused.returncode == 2 and f"error: {option}" in refused.stderr, (args, refused.stderr)
    assert not (tmp_path / "x.png").exists()


@pytest.mark.slow
def test_neural_bench_loaders_on_a_folder_and_its_publication(reference, tmp_path):
    pub = tmp_path / "pub"
    assert CliRunner().invoke(main, ["publish", str(reference), "--out", str(pub)]).exit_code == 0
    done = _cli("neural-bench", "loaders", reference, pub, "--repeats", 1)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("16 samples at 64 px") and [line.split(" |")[0] for line in lines[-2:]] == [
        "| folder",
        "| publication",
    ]
    swapped = _cli("neural-bench", "loaders", pub, reference, "--repeats", 1)
    assert swapped.returncode == 2 and "a dataset folder, then its publication as PUB" in swapped.stderr
    assert swapped.stderr.splitlines()[-1].startswith(f'error: DIR: "{pub}" is a publication; ')


@pytest.mark.slow
def test_neural_bench_collate_denoise_and_train_options(reference):
    collate = _cli("neural-bench", "collate", reference, "--repeats", 1, "--busy", 0, "--json")
    assert collate.returncode == 0, collate.stderr
    rows = json.loads(collate.stdout)["rows"]
    assert len(rows) == 4 and all(r["samples_per_s_median"] > 0 for r in rows)
    denoise = _cli("neural-bench", "denoise", reference, "--draws", 1, "--spp", 1, "--reference-spp", 4)
    assert denoise.returncode == 0, denoise.stderr
    assert denoise.stdout.startswith("| spp | OIDN fed |") and denoise.stdout.count("\n| 1 |") == 5
    train = _cli(
        "neural-bench", "train-options", "--resolution", 16, "--loss", "l1", "--repeats", 1, "--steps", 1,
        "--variants", "baseline", "--json",
    )  # fmt: skip
    assert train.returncode == 0, train.stderr
    assert [r["options"] for r in json.loads(train.stdout)["rows"]] == ["baseline"]
    refused = _cli("neural-bench", "collate", reference, "--loader-workers", 99)
    assert refused.returncode == 2 and "--loader-workers: 99" in refused.stderr
