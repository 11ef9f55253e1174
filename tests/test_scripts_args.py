"""Scripts are tools too: each checks its arguments before it removes or writes anything, and a
bad argument ends with one `error:` line and its usage on stderr, exit 2, no traceback.

Scripts that work on the repository they live in (they `cd` to it) run from a copy in a
scratch repository, so a script that removes first cannot touch this checkout's files.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCRIPTS = REPO / "scripts"


def _run(argv, cwd, env=None, timeout=300):
    done = subprocess.run(
        [str(a) for a in argv],
        cwd=cwd,
        env={**os.environ, **(env or {})},
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
    )
    return done


def _refused(done, *words):
    """Exit 2, an `error:` line naming ``words``, a usage line, no traceback."""
    err = done.stderr
    assert done.returncode == 2, (done.returncode, done.stdout[-2000:], err[-2000:])
    assert "Traceback" not in err and "error:" in err and "usage:" in err, err
    for word in words:
        assert word in err, (word, err)


def _tree(root: Path) -> list[str]:
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*"))


def _scratch_repo(tmp_path: Path, *scripts: str) -> Path:
    """A repository holding copies of ``scripts`` and a stub .venv/bin/shaderball that fails."""
    repo = tmp_path / "repo"
    (repo / "scripts").mkdir(parents=True)
    for name in scripts:
        shutil.copy2(SCRIPTS / name, repo / "scripts" / name)
    (repo / ".venv" / "bin").mkdir(parents=True)
    stub = repo / ".venv" / "bin" / "shaderball"
    stub.write_text("#!/bin/sh\nexit 1\n")
    stub.chmod(0o755)
    return repo


def test_same_outputs_checks_its_checkouts_before_it_clears_out(tmp_path):
    out = tmp_path / "OUT"
    (out / "A").mkdir(parents=True)
    (out / "A" / "mine.txt").write_text("keep")
    done = _run(["bash", SCRIPTS / "same_outputs.sh", "/nonexistent", "/nonexistent", out], tmp_path)
    _refused(done, "/nonexistent", "not a shaderball checkout")
    assert _tree(out) == ["A", "A/mine.txt"]


def test_same_outputs_keeps_an_out_folder_it_did_not_write(tmp_path):
    """Checkouts that look right (a stub python that fails): OUT/A holds the user's file."""
    checkout = tmp_path / "checkout"
    (checkout / "manifests").mkdir(parents=True)
    (checkout / "cli.py").write_text("")
    (checkout / "manifests" / "smoke.toml").write_text("")
    (checkout / ".venv" / "bin").mkdir(parents=True)
    python = checkout / ".venv" / "bin" / "python"
    python.write_text("#!/bin/sh\nexit 1\n")
    python.chmod(0o755)
    out = tmp_path / "OUT"
    (out / "A").mkdir(parents=True)
    (out / "A" / "mine.txt").write_text("keep")
    done = _run(["bash", SCRIPTS / "same_outputs.sh", checkout, checkout, out], tmp_path)
    _refused(done, "OUT", "name another OUT")
    assert _tree(out) == ["A", "A/mine.txt"]
    assert _run(["bash", SCRIPTS / "same_outputs.sh", checkout, checkout], tmp_path).returncode == 2


def test_neural_repro_docs_keeps_the_docs_when_out_lacks_the_sweep(tmp_path):
    repo = _scratch_repo(tmp_path, "neural_repro_docs.sh")
    docs = repo / "docs" / "results" / "neural-mini"
    docs.mkdir(parents=True)
    (docs / "sweep.md").write_text("the published results")
    before = _tree(repo)
    done = _run(["bash", repo / "scripts" / "neural_repro_docs.sh", tmp_path / "nothing-here"], tmp_path)
    _refused(done, "nothing-here", "sweep/sweep.md")
    assert _tree(repo) == before


def test_readme_pictures_keeps_a_work_folder_it_did_not_write(tmp_path):
    repo = _scratch_repo(tmp_path, "readme_pictures.sh")
    work = tmp_path / "my-folder"
    work.mkdir()
    (work / "thesis.tex").write_text("mine")
    before = _tree(tmp_path)
    done = _run(["bash", repo / "scripts" / "readme_pictures.sh", work], tmp_path)
    _refused(done, "thesis.tex", "name another")
    assert _tree(tmp_path) == before


@pytest.mark.parametrize("script", ["neural_default_check.sh", "neural_repro.sh"])
def test_neural_checks_refuse_extra_arguments_and_a_file_as_out(tmp_path, script):
    repo = _scratch_repo(tmp_path, script)
    (repo / "manifests").mkdir()
    shutil.copy2(REPO / "manifests" / "smoke.toml", repo / "manifests" / "smoke.toml")
    before = _tree(tmp_path)
    _refused(_run(["bash", repo / "scripts" / script, "out-a", "out-b"], tmp_path), "at most 1 argument")
    a_file = tmp_path / "a-file"
    a_file.write_text("x")
    before = _tree(tmp_path)
    _refused(_run(["bash", repo / "scripts" / script, a_file], tmp_path), "a-file", "not a folder")
    assert _tree(tmp_path) == before


def test_bench_train_speed_checks_its_dataset_before_it_starts(tmp_path):
    repo = _scratch_repo(tmp_path, "bench_train_speed.sh")
    done = _run(["bash", repo / "scripts" / "bench_train_speed.sh", tmp_path / "no-dataset"], tmp_path)
    _refused(done, "no-dataset", "manifest.jsonl")
    assert "shaderball train" not in done.stdout


def test_gpu_check_refuses_to_run_outside_the_repository(tmp_path):
    out = tmp_path / "logs"
    done = _run(["bash", SCRIPTS / "gpu_check.sh"], tmp_path, env={"OUT": str(out), "SB": "/bin/false"})
    _refused(done, "repository root")
    assert not out.exists()


def test_suite_under_load_checks_its_log_before_it_clones(tmp_path):
    done = _run(["bash", SCRIPTS / "suite_under_load.sh", tmp_path / "missing" / "suite.log"], tmp_path)
    _refused(done, "missing", "does not exist")


def test_crash_test_checks_its_spec_before_it_clears_the_work_folder(tmp_path):
    work = tmp_path / "work"
    (work / "reference").mkdir(parents=True)
    (work / "reference" / "keep.txt").write_text("a finished reference build, say")
    done = _run([sys.executable, SCRIPTS / "crash_test.py", "--spec", tmp_path / "none.toml", "--work", work], REPO)
    _refused(done, "--spec", "none.toml")
    assert _tree(work) == ["reference", "reference/keep.txt"]


@pytest.mark.parametrize("script", ["spec_reference.py", "layers.py"])
def test_write_scripts_refuse_an_unknown_argument(tmp_path, script):
    """``--wrte`` (a typo) used to be ignored: the page printed, nothing said."""
    done = _run([sys.executable, SCRIPTS / script, "--wrte"], REPO)
    _refused(done, "--wrte", "[--write]")
    assert done.stdout == ""


def test_plan_check_checks_out_before_it_plans(tmp_path):
    a_file = tmp_path / "a-file"
    a_file.write_text("x")
    done = _run([sys.executable, SCRIPTS / "plan_check.py", tmp_path / "none.toml", "--out", a_file], REPO)
    _refused(done, "--out", "not a folder")
    assert a_file.read_text() == "x"


def test_hub_contact_sheet_checks_its_arguments_before_it_draws(tmp_path):
    done = _run([sys.executable, SCRIPTS / "hub_contact_sheet.py", tmp_path / "no-pub", tmp_path / "x.png"], REPO)
    _refused(done, "no-pub")
    assert not (tmp_path / "x.png").exists()


def test_scene_bench_refuses_extra_arguments_before_writing(tmp_path):
    repo = _scratch_repo(tmp_path, "scene_bench.sh")
    work = tmp_path / "work"
    done = _run(["sh", repo / "scripts" / "scene_bench.sh", work, "extra"], repo)
    _refused(done, "at most one argument")
    assert not work.exists()
