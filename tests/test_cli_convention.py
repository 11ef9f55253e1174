"""The command-line convention, over every command of `shaderball` (commands added later
are covered: the tests walk ``cli.main.commands``, and a group's subcommands).

- ``--json`` is a flag, and prints exactly one JSON document on stdout whatever happens
  (the README's sentence); a file of figures is ``--json-out FILE``;
- ``--workers`` means dask worker processes; the DataLoader's is ``--loader-workers``;
- "the first N samples" is ``--limit``; no option is named ``--samples``;
- every option has help text, and an option its help calls required is marked so;
- ``--out``'s help says whether it is a file or a folder;
- an old spelling exits 2 with a message naming the new one, and no traceback.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

import cli
from scripts import cli_reference

REPO = Path(__file__).resolve().parents[1]
SMOKE = str(REPO / "manifests" / "smoke.toml")
#: Every command that runs something: the group's commands and a group's subcommands (a
#: group itself, `neural-bench`, only lists its own).
COMMANDS = sorted(
    (name, command)
    for name in cli_reference.command_names()
    if not isinstance(command := cli_reference.command_for(name), click.Group)
)


def visible_options(command: click.Command):
    return [p for p in command.params if isinstance(p, click.Option) and not p.hidden]


def invoke(*args) -> click.testing.Result:
    return CliRunner().invoke(cli.main, [str(a) for a in args])


@pytest.mark.parametrize("name, command", COMMANDS)
def test_every_option_has_help_and_follows_the_names(name, command):
    for option in visible_options(command):
        where = f"{name} {'/'.join(option.opts)}"
        assert option.help and option.help.strip(), f"{where}: no help text"
        assert "--samples" not in option.opts, f"{where}: 'first N samples' is --limit; draws are --draws"
        if "--json" in option.opts:
            assert option.is_flag and option.name == "as_json", f"{where}: --json is a flag; a file is --json-out FILE"
        if "--json-out" in option.opts:
            assert not option.is_flag, where
        if "--workers" in option.opts:
            assert "dask" in option.help.lower(), f"{where}: --workers means dask worker processes; say so"
        if "--out" in option.opts:
            assert re.search(r"\b(file|folder)\b", option.help, re.I), f"{where}: say whether --out is a file or folder"
        if "[required" in option.help or option.help.lower().startswith("required"):
            assert option.required or "except with" in option.help, f"{where}: its help says required; mark it"


#: Commands without --json: serve runs a web server until it is stopped.
NO_JSON = {"serve"}


def test_every_command_that_reports_takes_json():
    without = {n for n, c in COMMANDS if not any(p.name == "as_json" for p in c.params)}
    assert without == NO_JSON


@pytest.mark.parametrize("name, command", [(n, c) for n, c in COMMANDS if any(p.name == "as_json" for p in c.params)])
def test_json_prints_exactly_one_document_on_a_refusal(name, command, tmp_path):
    """The README: "With --json a command prints exactly one JSON document on stdout whatever
    happens (on failure {"ok": false, "exit": N, "error": ...})". A command given paths
    that do not exist, and no options, with --json is refused: one document, ok false."""
    arguments = [p for p in command.params if isinstance(p, click.Argument)]
    args = [*name.split()] + [str(tmp_path / "missing")] * len(arguments) + ["--json"]
    if not any(p.required for p in command.params):  # nothing missing to refuse: an unknown option
        args.append("--not-an-option")
    result = CliRunner().invoke(cli.main, args)
    assert result.exit_code != 0, result.output
    doc = json.loads(result.stdout)  # exactly one document: json.loads refuses trailing data
    assert doc["ok"] is False and doc["exit"] == result.exit_code and doc["error"], doc


@pytest.mark.parametrize(
    "args",
    [
        ["info", SMOKE, "--json"],
        ["plan", SMOKE, "--no-timing", "--json"],
    ],
)
def test_json_prints_exactly_one_document_on_success(args):
    result = invoke(*args)
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert isinstance(doc, dict) and doc


@pytest.mark.parametrize(
    "args, new",
    [
        (["train", "DATA", "--out", "RUN", "--workers", "2"], "--loader-workers"),
        (["bench", SMOKE, "--samples", "4"], "--limit"),
        (["plan", SMOKE, "--samples", "4"], "--limit"),
        (["preview", "DIR", "--out", "x.png", "--samples", "4"], "--limit"),
        (["study", SMOKE, "--out", "S", "--samples", "4"], "--draws"),
        (["bench", SMOKE, "--json", "bench.json"], "--json-out"),
        (["evaluate", "RUN", "DATA", "--json", "results.json"], "--json-out"),
    ],
)
def test_an_old_spelling_exits_2_naming_the_new_one(args, new, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the relative paths above
    result = CliRunner().invoke(cli.main, args)
    assert not list(tmp_path.iterdir()), "nothing is written"
    assert result.exit_code == 2, result.output
    assert new in result.output and "Traceback" not in result.output, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)


def test_train_has_no_dask_workers_and_its_loader_workers_say_so():
    options = {o: p for p in cli.main.commands["train"].params for o in getattr(p, "opts", ())}
    assert "--loader-workers" in options and "dataloader" in options["--loader-workers"].help.lower()
    assert options["--workers"].hidden
