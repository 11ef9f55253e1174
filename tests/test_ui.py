"""pipeline.ui: the command's progress lines off a terminal, and its value parsing's refusals."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from pipeline.ui import progress


def test_format_seconds():
    assert [progress.format_seconds(s) for s in (None, 0, 65.9, 3605)] == ["--:--", "0:00", "1:05", "1:00:05"]


def test_a_build_off_a_terminal_prints_whole_lines_only_when_something_changes(capsys):
    show = progress.build_progress()  # pytest's stderr is no terminal
    step = dict(total=4, rate=0.5, elapsed_s=2.0, eta_s=4.0)
    show(SimpleNamespace(done=1, message="", **step))
    show(SimpleNamespace(done=1, message="", **step))  # nothing changed: nothing printed
    show(SimpleNamespace(done=1, message="waiting for a worker (none connected)", **step))
    show(SimpleNamespace(done=4, message="", **step))
    lines = capsys.readouterr().err.split("\n")
    assert "\r" not in "".join(lines) and lines[-1] == ""
    assert lines[:-1] == [
        "[#######.......................] 1/4 renders  25.0%  0.50/s  elapsed 0:02  ETA 0:04",
        "[#######.......................] 1/4 renders  25.0%  0.50/s  elapsed 0:02  ETA 0:04"
        "  | waiting for a worker (none connected)",
        "[##############################] 4/4 renders 100.0%  0.50/s  elapsed 0:02  ETA 0:04",
    ]


def test_training_off_a_terminal_prints_a_line_per_batch(capsys):
    show = progress.training_progress()
    p = dict(epoch=1, epochs=2, batches=2, loss=0.25, samples_per_s=3.0, eta_s=None)
    show({"note": "loss: l1 (--loss l1)"})
    show({**p, "batch": 1})
    show({**p, "batch": 2})
    assert capsys.readouterr().err.splitlines() == [
        "loss: l1 (--loss l1)",
        "epoch 1/2 [##########..........] batch 1/2  loss 0.2500  3.0 samples/s  ETA --:--",
        "epoch 1/2 [####################] batch 2/2  loss 0.2500  3.0 samples/s  ETA --:--",
    ]


def test_evaluate_off_a_terminal_prints_a_bar_line_per_step_saying_what_runs(capsys):
    show = progress.evaluate_progress()
    show(dict(done=0, total=4, rate=0.0, elapsed_s=0.5, eta_s=None, what="m000000_l0: network"))
    show(dict(done=1, total=4, rate=0.25, elapsed_s=4.0, eta_s=12.0, what="m000000_l0: done"))
    assert capsys.readouterr().err.splitlines() == [
        "[..............................] 0/4 samples   0.0%  0.00/s  elapsed 0:00  ETA --:--  | m000000_l0: network",
        "[#######.......................] 1/4 samples  25.0%  0.25/s  elapsed 0:04  ETA 0:12  | m000000_l0: done",
    ]


def test_int_lists_are_one_rule():
    """A comma-separated list of integers is the IntList rule: parsed from the command line,
    refused in the project's one form."""
    from pipeline.fields.rules import IntList, Reject

    rule = IntList(1, 4096, none="none")
    assert rule.check(rule.parse("1,2,16")) == (1, 2, 16)
    assert rule.check(rule.parse(" None ")) == ()
    with pytest.raises(ValueError):
        rule.parse("1,x")
    with pytest.raises(Reject):
        rule.check((0, 2))
    assert rule.allowed == "comma-separated integers from 1 to 4096, or none"


def test_the_neural_commands_help_says_the_ranges_their_checks_use():
    """train's and evaluate's ranges live in pipeline.neural.limits (no torch), which both
    the checks and the CLI's help read: the help says what the checks allow."""
    from click.testing import CliRunner

    from cli import main
    from pipeline.neural.limits import DEVICES, INTEGER_RANGES, SPP_LADDER_RANGE
    from pipeline.render.limits import span

    def help_of(command):
        result = CliRunner().invoke(main, [command, "--help"])
        assert result.exit_code == 0
        return " ".join(result.output.split())

    train = help_of("train")
    for name, bounds in INTEGER_RANGES.items():
        assert f"--{name.replace('_', '-')}" in train and span(bounds) in train, name
    assert f"Allowed: {span(SPP_LADDER_RANGE)} each, or none." in help_of("evaluate")
    assert f"[{'|'.join(DEVICES)}]" in train
