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


def test_every_command_takes_json():
    """serve too: its summary, or with --benchmark its figures (the address goes to stderr)."""
    without = {n for n, c in COMMANDS if not any(p.name == "as_json" for p in c.params)}
    assert without == set()


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
        (["bench", SMOKE, "--samples", "4"], "--renders"),
        (["bench", SMOKE, "--limit", "4"], "--renders"),
        (["plan", SMOKE, "--samples", "4"], "--renders"),
        (["plan", SMOKE, "--limit", "4"], "--renders"),
        (["preview", "DIR", "--out", "x.png", "--samples", "4"], "--rows"),
        (["preview", "DIR", "--out", "x.png", "--limit", "4"], "--rows"),
        (["study", SMOKE, "--out", "S", "--samples", "4"], "--draws"),
        (["bench", SMOKE, "--json", "bench.json"], "--json-out"),
        (["evaluate", "RUN", "DATA", "--json", "results.json"], "--json-out"),
        (["evaluate", "RUN", "DATA", "--samples", "2"], "--limit"),
        (["neural-bench", "denoise", "DATA", "--samples", "1"], "--draws"),
        (["neural-bench", "denoise", "DATA", "--limit", "1"], "--draws"),
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


# ----------------------------------------------------------------- one declared request per command


def _request_fields(command) -> dict:
    """The request's fields and its parts' (pipeline.fields.flattened)."""
    from pipeline.fields import flattened

    return {name: f for name, (f, _) in flattened(command.request_cls).items()}


@pytest.mark.parametrize("name, command", COMMANDS)
def test_every_command_is_generated_from_one_request(name, command):
    """Every visible option and operand is a field of the command's request or of one of its
    parts: nothing is declared by hand in cli.py (only --json and --help are the command
    line's own)."""
    assert getattr(command, "request_cls", None) is not None, f"{name}: not made by request_command"
    fields = _request_fields(command)
    for param in command.params:
        if isinstance(param, click.Option) and (param.hidden or param.name in ("as_json", "help")):
            continue
        assert param.name in fields, f"{name} {'/'.join(param.opts)}: not a field of {command.request_cls.__name__}"


@pytest.mark.parametrize("name, command", COMMANDS)
def test_every_numeric_option_shows_its_range(name, command):
    for option in visible_options(command):
        kind = getattr(option.type, "rule", None)
        inner = getattr(kind, "rule", kind)
        if type(inner).__name__ in ("Int", "Float", "IntList") or option.type in (click.INT, click.FLOAT):
            assert "Allowed:" in option.help, f"{name} {option.opts[0]}: its help shows no range"


@pytest.mark.parametrize("name, command", COMMANDS)
def test_limit_means_the_first_n_samples_everywhere(name, command):
    for option in visible_options(command):
        if "--limit" in option.opts:
            assert "first" in option.help.lower(), f"{name} --limit: means 'at most the first N samples' only"


def _choice_options():
    for name, command in COMMANDS:
        for option in visible_options(command):
            rule = getattr(option.type, "inner", None)
            if type(rule).__name__ == "Choice" or isinstance(option.type, click.Choice):
                yield name, command, option


@pytest.mark.parametrize("name, command, option", list(_choice_options()), ids=lambda v: getattr(v, "name", v))
def test_a_refused_choice_reads_in_the_project_form(name, command, option, tmp_path):
    operands = [str(tmp_path)] * sum(isinstance(p, click.Argument) and p.required for p in command.params)
    result = CliRunner().invoke(cli.main, [*name.split(), *operands, option.opts[0], "not-a-choice", "--json"])
    assert result.exit_code == 2, result.output
    doc = json.loads(result.stdout)
    assert doc["error"].startswith(f'{option.opts[0]}: "not-a-choice" is not allowed; one of '), doc
    assert "Invalid value" not in result.output


JSON_COMMANDS = [(n, c) for n, c in COMMANDS if any(p.name == "as_json" for p in c.params)]


#: ``--json out.json`` is refused by every command: where a command's operands are JSON files
#: (sweep's REPORT.json...), a name that is no file is the output meant, not a report to read.
JSON_VALUE_CASES = [
    (name, command, form) for name, command in JSON_COMMANDS for form in ("--json=out.json", "--json out.json")
]


@pytest.mark.parametrize("name, command, form", JSON_VALUE_CASES)
def test_json_given_a_value_is_one_document_naming_json_out(name, command, form, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    operands = ["missing"] * sum(isinstance(p, click.Argument) and p.required for p in command.params)
    result = CliRunner().invoke(cli.main, [*name.split(), *operands, *form.split()])
    assert result.exit_code == 2, result.output
    doc = json.loads(result.stdout)  # exactly one document
    assert doc["ok"] is False and "--json is a flag" in doc["error"], doc
    if any("--json-out" in p.opts for p in visible_options(command)):
        assert "--json-out" in doc["error"], doc
    assert not list(tmp_path.iterdir()), "nothing is written"


@pytest.mark.parametrize("args", [["info", SMOKE, "--json"], ["plan", SMOKE, "--no-timing", "--json"]])
def test_a_success_document_says_ok(args):
    result = invoke(*args)
    doc = json.loads(result.stdout)
    assert result.exit_code == 0 and doc["ok"] is True and doc["exit"] == 0, doc


def test_a_missing_operand_says_it_does_not_exist(tmp_path):
    nope = tmp_path / "nope"
    for args in (["verify", nope], ["validate", nope], ["info", nope], ["sweep", nope, "--out", tmp_path / "s"]):
        result = invoke(*args)
        assert result.exit_code == 2 and "does not exist" in result.output and "Errno" not in result.output, args


#: Library modules that print nothing and parse nothing: the command line is theirs to spell.
LIBRARY = [p for p in (REPO / "pipeline").rglob("*.py") if "ui" not in p.relative_to(REPO / "pipeline").parts[:1]]


def _refusal_texts(path: Path):
    """The first string piece of every exception raised in ``path`` (its message's head)."""
    import ast

    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Raise) and isinstance(node.exc, ast.Call) and node.exc.args:
            first = node.exc.args[0]
            if isinstance(first, ast.JoinedStr) and first.values and isinstance(first.values[0], ast.Constant):
                first = first.values[0]
            if isinstance(first, ast.Constant) and isinstance(first.value, str):
                yield node.lineno, first.value


@pytest.mark.parametrize("path", LIBRARY, ids=lambda p: str(p.relative_to(REPO)))
def test_the_library_names_fields_not_options(path):
    """A refusal in library code names the field (FieldError by name), never the command
    line's spelling of it: no message that starts with an option or an operand's metavar."""
    bad = [
        f"{path.relative_to(REPO)}:{line}: {text[:60]!r}"
        for line, text in _refusal_texts(path)
        if re.match(r"(--[a-z]|[A-Z]+(\|[A-Z]+)*: )", text)
    ]
    assert not bad, bad
    source = path.read_text()
    assert "bad_value(" not in source and "check_int(" not in source, f"{path}: refuse by the field rules"


def test_a_refusal_and_the_help_say_the_same_range():
    """validate --repair --workers: its help's range and default are the ones a refusal names."""
    option = next(p for p in cli.main.commands["validate"].params if p.name == "workers")
    result = invoke("validate", SMOKE, "--repair", "--workers", "-1")
    assert result.exit_code == 2
    allowed = result.output.split("is not allowed; ")[1].strip()
    assert allowed == "an integer from 0 to 1024" and "Allowed: 0 to 1024" in option.help, (allowed, option.help)
    assert option.default == 0 and "unset" not in result.output
