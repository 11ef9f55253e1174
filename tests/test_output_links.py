"""No output through a link (pipeline.store.links): a command that writes into a run folder
(evaluate's default RUN/evaluation-<split>, train's run files, export's and infer's files
inside RUN) or into its output folder (evaluate --out, sweep --out) refuses a path that is, or
passes through, a symbolic link inside that folder, before it writes anything: exit 2, naming
the path; nothing is written outside, and no link is replaced."""

import json
import os
import shutil

import pytest
from click.testing import CliRunner

from cli import main
from pipeline.store.atomic import write_bytes_atomic
from pipeline.store.links import ThroughLink, first_link, link_below
from support.neural_fakes import TINY


def _invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture
def outside(tmp_path):
    """A folder outside every run, holding one file: what a link points to."""
    folder = tmp_path / "outside"
    folder.mkdir()
    (folder / "precious.txt").write_text("mine")
    return folder


def _state(folder):
    """Every entry under ``folder``: its kind and bytes (or link target), links not followed."""
    found = {}
    for path in sorted(folder.rglob("*")):
        rel = str(path.relative_to(folder))
        found[rel] = os.readlink(path) if path.is_symlink() else (path.read_bytes() if path.is_file() else "dir")
    return found


def _refused(result, words):
    assert result.exit_code == 2, (result.exit_code, result.output)
    assert words in result.output and "symbolic link" in result.output, result.output
    assert "nothing is written through a link" in result.output and "Traceback" not in result.output


def _evaluate(run_dir, reference, *more):
    return _invoke("evaluate", run_dir, reference, "--spp", "none", "--limit", 2, *more)


@pytest.mark.slow
def test_evaluate_refuses_a_default_folder_that_is_a_link(tiny_run, reference, tmp_path, outside):
    copy = shutil.copytree(tiny_run, tmp_path / "run")
    (copy / "evaluation-all").symlink_to(outside)
    before, outside_before = _state(copy), _state(outside)
    result = _evaluate(copy, reference, "--split", "all")
    _refused(result, f"--out: {copy / 'evaluation-all'} is a symbolic link (to '{outside}')")
    assert _state(outside) == outside_before and _state(copy) == before


@pytest.mark.slow
@pytest.mark.parametrize("name", ["results.json", "grid.png", "report.md", "learning-curve.csv"])
def test_evaluate_refuses_a_file_of_its_folder_that_is_a_link(tiny_run, reference, tmp_path, outside, name):
    copy = shutil.copytree(tiny_run, tmp_path / "run")
    (copy / "evaluation-test").mkdir()
    (copy / "evaluation-test" / name).symlink_to(outside / "precious.txt")
    before, outside_before = _state(copy), _state(outside)
    result = _evaluate(copy, reference, "--report")
    _refused(result, f"{copy / 'evaluation-test' / name} is a symbolic link")
    assert _state(outside) == outside_before and _state(copy) == before


@pytest.mark.slow
def test_evaluate_refuses_an_out_folder_or_json_out_through_a_link_in_the_run(tiny_run, reference, tmp_path, outside):
    copy = shutil.copytree(tiny_run, tmp_path / "run")
    (copy / "elsewhere").symlink_to(outside)
    before, outside_before = _state(copy), _state(outside)
    result = _evaluate(copy, reference, "--out", copy / "elsewhere" / "ev")
    _refused(result, f"--out: {copy / 'elsewhere'} is a symbolic link")
    result = _evaluate(copy, reference, "--out", tmp_path / "ev", "--json-out", copy / "elsewhere" / "r.json")
    _refused(result, f"--json-out: {copy / 'elsewhere'} is a symbolic link")
    own = tmp_path / "ev"  # an out folder of the user's own, outside the run: its files are checked too
    own.mkdir(exist_ok=True)
    (own / "results.md").symlink_to(outside / "precious.txt")
    result = _evaluate(copy, reference, "--out", own)
    _refused(result, f"--out: {own / 'results.md'} is a symbolic link")
    assert _state(outside) == outside_before and _state(copy) == before
    assert sorted(os.listdir(own)) == ["results.md"]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["log.jsonl", "loss.png", "checkpoint-best.pt", "log.csv"])
def test_a_resumed_run_refuses_a_run_file_that_is_a_link(tiny_run, reference, tmp_path, outside, name):
    copy = shutil.copytree(tiny_run, tmp_path / "run")
    target = outside / "precious.txt"
    if (copy / name).exists():
        os.remove(copy / name)
    (copy / name).symlink_to(target)
    before, outside_before = _state(copy), _state(outside)
    result = _invoke("train", reference, "--out", copy, "--epochs", 2, *TINY)
    _refused(result, f"--out: {copy / name} is a symbolic link (to '{target}')")
    assert _state(outside) == outside_before and _state(copy) == before


@pytest.mark.slow
def test_export_and_infer_refuse_a_file_inside_the_run_through_a_link(tiny_run, tmp_path, outside):
    copy = shutil.copytree(tiny_run, tmp_path / "run")
    (copy / "elsewhere").symlink_to(outside)
    (copy / "net.pt").symlink_to(outside / "precious.txt")
    before, outside_before = _state(copy), _state(outside)
    _refused(_invoke("export", copy, "--out", copy / "elsewhere" / "net.pt"), f"{copy / 'elsewhere'} is a symbolic")
    _refused(_invoke("export", copy, "--out", copy / "net.pt"), f"--out: {copy / 'net.pt'} is a symbolic link")
    _refused(
        _invoke("infer", copy, "--out", copy / "elsewhere" / "ball.exr"), f"--out: {copy / 'elsewhere'} is a symbolic"
    )
    result = _invoke("infer", copy, "--out", tmp_path / "ball.exr", "--png", copy / "elsewhere" / "ball.png")
    _refused(result, f"--png: {copy / 'elsewhere'} is a symbolic link")
    assert _state(outside) == outside_before and _state(copy) == before
    assert not (tmp_path / "ball.exr").exists()


def test_sweep_refuses_a_file_of_its_out_folder_that_is_a_link(tmp_path, outside):
    rows = [
        {"id": f"m{m:06d}_l0", "material_id": f"m{m:06d}", "class": "uniform", "network": {"psnr": 20.0 + m}}
        for m in range(4)
    ]
    mean = {"network": {"psnr": 21.5, "ci95": {"psnr": [20.0, 23.0]}}}
    doc = {"samples": rows, "mean": mean, "run_options": {"seed": 1}, "train_renders": 4, "history": []}
    report = tmp_path / "report.json"
    report.write_text(json.dumps(doc))
    out = tmp_path / "sweep"
    out.mkdir()
    (out / "sweep.json").symlink_to(outside / "precious.txt")
    outside_before = _state(outside)
    result = _invoke("sweep", report, "--out", out)
    _refused(result, f"--out: {out / 'sweep.json'} is a symbolic link")
    assert _state(outside) == outside_before and sorted(os.listdir(out)) == ["sweep.json"]


def test_link_below_checks_every_component_below_the_folder_however_it_is_spelled(tmp_path, outside):
    root = tmp_path / "run"
    (root / "real").mkdir(parents=True)
    (root / "link").symlink_to(outside)
    (root / "file.txt").symlink_to(outside / "precious.txt")
    alias = tmp_path / "alias"
    alias.symlink_to(root)  # the folder itself may be a link: the user named it
    assert link_below(root, root / "real" / "new" / "x.json") is None  # not there yet: made as real folders
    assert link_below(root, root) is None and link_below(alias, alias / "real" / "x") is None
    assert link_below(root, tmp_path / "other" / "x") is None  # not inside
    for folder, path in [(root, root / "link" / "x"), (alias, alias / "link" / "x"), (root, alias / "link" / "x")]:
        why = link_below(folder, path)
        assert why and f"/link is a symbolic link (to '{outside}') inside {folder}" in why, (folder, path, why)
    assert "file.txt is a symbolic link" in link_below(root, root / "file.txt")
    assert first_link([None, root], [root / "real" / "a", root / "file.txt"])[0] == root / "file.txt"


def test_the_atomic_writer_refuses_a_link_inside_the_folder_it_writes(tmp_path, outside):
    root = tmp_path / "run"
    root.mkdir()
    (root / "sub").symlink_to(outside)
    with pytest.raises(ThroughLink, match=r"sub/x.json: not written: .*sub is a symbolic link"):
        write_bytes_atomic(str(root / "sub" / "x.json"), b"{}", inside=str(root))
    assert sorted(os.listdir(outside)) == ["precious.txt"]
    write_bytes_atomic(str(root / "ok.json"), b"{}", inside=str(root))
    assert (root / "ok.json").read_bytes() == b"{}"
