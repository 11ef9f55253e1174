"""A number on the command line is ASCII digits. Python's int() and float() also read other
scripts' digits ("１" full-width, "٣" Arabic-Indic) and underscores ("1_0"): `--gpus １` used to
pass as 1, then fail later ("0 GPU(s) visible here") with the output folder already written."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from cli import main

SMOKE = Path(__file__).resolve().parents[1] / "manifests" / "smoke.toml"
NOT_ASCII = ["１", "٣", "1_0", "１６"]


def _refused(args, option, value, tmp_path):
    before = sorted(tmp_path.rglob("*"))
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert result.exit_code == 2, result.output
    assert f"error: {option}: " in result.output and f"{value}" in result.output, result.output
    assert "is not allowed" in result.output, result.output
    assert sorted(tmp_path.rglob("*")) == before  # nothing written


@pytest.mark.parametrize("gpus", ["１", "0,１", "٣,", "1_0"])
def test_gpus_takes_ascii_digits_only(tmp_path, gpus):
    _refused(["build", SMOKE, "--out", tmp_path / "out", "--gpus", gpus], "--gpus", gpus, tmp_path)


@pytest.mark.parametrize("option,value", [("--spp", "１６"), ("--resolution", "٣2"), ("--roughness", "０.５")])
def test_int_and_float_options_take_ascii_digits_only(tmp_path, option, value):
    _refused(["render", "--out", tmp_path / "ball.exr", option, value], option, value, tmp_path)


def test_the_rules_parse_ascii_only():
    from pipeline.fields.rules import Float, Int, IntList, Triple

    for text in NOT_ASCII:
        for rule in (Int(0, 100), Float(0, 100), IntList(0, 100), Triple(0, 100)):
            with pytest.raises(ValueError):
                rule.parse(text)
    assert Int(0, 100).parse(" 42 ") == 42 and Int(-5, 5).parse("-3") == -3
    assert Float(0, 1).parse("1e-3") == 0.001 and Float(0, 1).parse(".5") == 0.5
    assert IntList(0, 9).parse("0,2") == (0, 2) and Triple().parse("0.5,1,0") == (0.5, 1.0, 0.0)


def test_memory_takes_ascii_digits_only():
    from pipeline.fields import FieldError
    from pipeline.run.cluster.options import memory_bytes

    assert memory_bytes("16GiB") == 16 * 2**30
    with pytest.raises(FieldError, match="memory"):
        memory_bytes("１６GiB")


def test_render_threads_from_the_environment_take_ascii_digits_only(monkeypatch):
    """ "²".isdigit() is True and int("²") raises: a worker used to die on it."""
    import os

    from pipeline.run.cluster.worker_env import RENDER_THREADS_ENV, worker_render_threads

    cpus = len(os.sched_getaffinity(0))
    for text in ("²", "１"):
        monkeypatch.setenv(RENDER_THREADS_ENV, text)
        assert worker_render_threads() == cpus
    monkeypatch.setenv(RENDER_THREADS_ENV, "3")
    assert worker_render_threads() == 3
