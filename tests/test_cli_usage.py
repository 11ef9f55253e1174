"""Every refusal of the command line in one form, over every command (walked from
``cli.main.commands``, a group's subcommands included, so a command added later is covered):

- click's own refusals (an operand or a required option left out, an unknown option, a word
  too many, an unknown command) read ``error: OPT: ...``, exit code 2, no "Usage:" block;
  a value left out reads one way for every command: ``OPT: missing; <what is allowed>``;
- with --json each of them is one JSON document on stdout, the message on stderr;
- a refused value is echoed as it was typed (``--spp: 0,1``, never ``[0, 1]``);
- one quoting style (double quotes) and one wording ("written by", "a spec file") in the help
  texts, the fields' words and the refusals; help in one order (``Allowed: ...`` before a
  ``[default: ...]``); a group's usage and text name its command word alike;
- a stdout whose reader has gone ends the command quietly: exit 141, nothing on stderr.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

import cli
from pipeline.fields import flattened
from pipeline.fields.rules import IntList, StrList, Triple

REPO = Path(__file__).resolve().parents[1]
SMOKE = str(REPO / "manifests" / "smoke.toml")


def _walk(group: click.Group, words: tuple[str, ...] = ()):
    for name, command in sorted(group.commands.items()):
        if isinstance(command, click.Group):
            yield from _walk(command, (*words, name))
        else:
            yield " ".join((*words, name)), command


COMMANDS = list(_walk(cli.main))
GROUPS = [("", cli.main)] + [(n, c) for n, c in sorted(cli.main.commands.items()) if isinstance(c, click.Group)]


def invoke(*args) -> click.testing.Result:
    return CliRunner().invoke(cli.main, [str(a) for a in args])


def _accepted(param: click.Parameter, candidates) -> str:
    """The first of ``candidates`` that ``param``'s type takes (a value its field's rule allows)."""
    ctx = click.Context(click.Command("x"))
    for value in candidates:
        try:
            param.type.convert(value, param, ctx)
            return value
        except Exception:  # noqa: BLE001 - a refusal of any kind: try the next
            continue
    raise AssertionError(f"{param.name}: no candidate value is accepted")


def _required(command):
    return [p for p in command.params if p.required]


def valid_args(command, tmp_path: Path, leave_out=None, every_operand: bool = False) -> list[str]:
    """Operands (``every_operand``: the optional ones too), then required options, each with a
    value its rule takes; ``leave_out``: a parameter not given (an operand: it and those
    after it)."""
    spec = tmp_path / "spec.toml"
    spec.write_text(Path(SMOKE).read_text())
    choices = [str(spec), str(tmp_path)]
    args: list[str] = []
    given = [p for p in command.params if p.required or (every_operand and isinstance(p, click.Argument))]
    for param in given:
        if param is leave_out and isinstance(param, click.Argument):
            break
        if param is leave_out:
            continue
        rule = getattr(param.type, "inner", None)
        names = list(getattr(rule, "options", None) or ())
        if isinstance(param, click.Argument):
            args.append(_accepted(param, [*choices, *names]))
        else:
            outs = [str(tmp_path / f"new{ext}") for ext in ("", ".exr", ".png", ".pt", ".json")]
            args += [param.opts[0], _accepted(param, [*outs, *names])]
    return args


def _where(param) -> str:
    return param.metavar if isinstance(param, click.Argument) else param.opts[0]


def refusal(result, code: int = 2) -> str:
    """The one line a refusal prints (on stderr), checked for the project's form; its message."""
    assert result.exit_code == code, (result.exit_code, result.output)
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "Usage:" not in result.output and "Traceback" not in result.output, result.output
    return lines[0].removeprefix("error: ")


#: Every required operand and option; and train's --out (required but with --benchmark).
MISSING_CASES = [(name, command, p) for name, command in COMMANDS for p in _required(command)] + [
    ("train", cli.main.commands["train"], next(p for p in cli.main.commands["train"].params if p.name == "out"))
]


@pytest.mark.parametrize("name, command, param", MISSING_CASES, ids=lambda v: getattr(v, "name", v))
def test_a_value_left_out_reads_one_way_for_every_command(name, command, param, tmp_path):
    """`build SPEC` with no --out, `evaluate` with no RUN: ``OPT: missing; <what is allowed>``
    (not "none is not allowed", nor click's "Missing argument 'RUN'")."""
    result = invoke(*name.split(), *valid_args(command, tmp_path, leave_out=param))
    message = refusal(result)
    assert message.startswith(f"{_where(param)}: missing; "), message
    assert len(message) > len(f"{_where(param)}: missing; ") + 3, "it says what is allowed"


@pytest.mark.parametrize("name, command", COMMANDS)
def test_an_unknown_option_reads_in_the_project_form(name, command, tmp_path):
    result = invoke(*name.split(), *valid_args(command, tmp_path), "--not-an-option")
    message = refusal(result)
    assert message.startswith("--not-an-option: unknown option; "), message
    assert f"{name} --help" in message, message


@pytest.mark.parametrize("name, command", COMMANDS)
def test_an_unknown_option_keeps_the_did_you_mean(name, command, tmp_path):
    options = [p for p in command.params if isinstance(p, click.Option) and not p.hidden]
    option = next((p for p in options if p.name != "as_json"), options[0])  # info has only --json
    typo = option.opts[0][:-1]  # "--limi"
    if any(typo in p.opts for p in command.params if isinstance(p, click.Option)):
        typo = option.opts[0] + "x"
    message = refusal(invoke(*name.split(), *valid_args(command, tmp_path), typo))
    assert message.startswith(f"{typo}: unknown option; "), message
    assert "did you mean" in message and option.opts[0] in message.split("did you mean")[1], message


#: Commands whose last operand takes any number of words have no word too many.
EXTRA_CASES = [
    (n, c) for n, c in COMMANDS if not any(isinstance(p, click.Argument) and p.nargs == -1 for p in c.params)
]


@pytest.mark.parametrize("name, command", EXTRA_CASES)
def test_a_word_too_many_reads_in_the_project_form(name, command, tmp_path):
    args = valid_args(command, tmp_path, every_operand=True)
    message = refusal(invoke(*name.split(), *args, "surplus-word"))
    assert message.startswith('"surplus-word": unexpected operand; '), message
    assert f"`main {name}` takes " in message, message


@pytest.mark.parametrize("group_name, group", GROUPS)
def test_an_unknown_command_reads_as_a_refused_choice(group_name, group):
    word = group.subcommand_metavar.split()[0]
    some = sorted(group.commands)[0]
    message = refusal(invoke(*group_name.split(), some[:-1] + "q"))
    assert message.startswith(f'{word}: "{some[:-1]}q" is not allowed; one of '), message
    assert f'"{some}"' in message and "did you mean" in message, message


# ----------------------------------------------------------------------------- --json: always JSON


def _json_cases():
    for name, command in COMMANDS:
        yield name, "unknown option", lambda tmp, c=command: [*valid_args(c, tmp), "--not-an-option"]
        if _required(command):
            yield name, "missing", lambda tmp, c=command: valid_args(c, tmp, leave_out=_required(c)[-1])
        if (name, command) in EXTRA_CASES:
            yield name, "extra", lambda tmp, c=command: [*valid_args(c, tmp, every_operand=True), "surplus"]
    for group_name, _ in GROUPS:
        yield group_name or "shaderball", "unknown command", lambda tmp: ["no-such-command"]


JSON_CASES = list(_json_cases())


@pytest.mark.parametrize("name, kind, make", JSON_CASES, ids=[f"{n}-{k}" for n, k, _ in JSON_CASES])
def test_every_refusal_with_json_is_one_document(name, kind, make, tmp_path):
    """`neural-bench foo --json` printed nothing on stdout: every refusal, click's included,
    prints one JSON document there (and its message on stderr)."""
    words = [] if name == "shaderball" else name.split()
    result = invoke(*words, *make(tmp_path), "--json")
    message = refusal(result)
    doc = json.loads(result.stdout)  # exactly one document: json.loads refuses trailing data
    assert doc["ok"] is False and doc["exit"] == 2 and doc["error"] == message, doc


def test_sweep_json_never_reads_the_next_word_as_a_report(tmp_path, monkeypatch):
    """`sweep REPORT --json out.json --out S`: out.json is what the user meant to write, not
    a report to read: refused naming --json's use, one document, nothing written."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "report.json").write_text("{}")
    result = invoke("sweep", "report.json", "--json", "out.json", "--out", "S")
    message = refusal(result)
    assert message.startswith("--json out.json: --json is a flag"), message
    assert json.loads(result.stdout)["error"] == message
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.json"]


# ----------------------------------------------------------------------------- values as typed


def _list_options():
    for name, command in COMMANDS:
        for option in command.params:
            rule = getattr(option.type, "inner", None)
            if isinstance(rule, IntList):
                yield name, command, option, f"{rule.lo},{rule.hi + 1}"
            elif isinstance(rule, StrList):
                yield name, command, option, "x,x"
            elif isinstance(rule, Triple):
                yield name, command, option, "1,2"
    render = cli.main.commands["render"]
    yield "render", render, next(p for p in render.params if p.name == "spp"), "0"  # a number, as typed too


LIST_OPTIONS = list(_list_options())


@pytest.mark.parametrize("name, command, option, typed", LIST_OPTIONS, ids=lambda v: getattr(v, "name", v))
def test_a_refused_value_is_echoed_as_typed(name, command, option, typed, tmp_path):
    message = refusal(invoke(*name.split(), *valid_args(command, tmp_path), option.opts[0], typed))
    assert message.startswith(f"{option.opts[0]}: {typed} is not allowed; "), message


# ----------------------------------------------------------------------------- one quoting, one wording

#: The minority forms: single-quoted words ('RUN', '/tmp/x': the project quotes values "so"),
#: "made by" (the project says "written by `shaderball build`"), "an existing spec file"
#: (the project says "a spec file"; that it must exist is the rule's, and its refusal's).
MINORITY = {
    "a single-quoted word": re.compile(r"(?<![\w.])'[^'\s]+'(?!\w)"),
    '"made by"': re.compile(r"\bmade by `"),
    '"an existing spec file"': re.compile(r"\ban existing spec file\b"),
}


def _texts(tmp_path):
    """Every help page, every declared field's help and allowed words, and click's refusals
    of each command (a value left out, an unknown option, an unknown command)."""
    for group_name, _ in GROUPS:
        yield f"{group_name or 'shaderball'} --help", invoke(*group_name.split(), "--help").output
        yield f"{group_name or 'shaderball'} unknown command", invoke(*group_name.split(), "nope").output
    for name, command in COMMANDS:
        yield f"{name} --help", invoke(*name.split(), "--help").output
        for f, _ in flattened(command.request_cls).values():
            rule = f.metadata["rule"]
            yield f"{name} {f.name}", f"{f.metadata['doc']} {rule.allowed} {getattr(rule, 'item', rule).allowed}"
        yield f"{name} unknown option", invoke(*name.split(), *valid_args(command, tmp_path), "--nope").output
        for param in _required(command):
            yield f"{name} no {param.name}", invoke(*name.split(), *valid_args(command, tmp_path, param)).output
    for name, command in NEURAL_OPERANDS:
        yield f"{name} a bad folder", _bad_folder(name, command, tmp_path)[1].output


#: The neural commands that read a folder (a dataset, a run, a report) named by an operand.
NEURAL_OPERANDS = [
    (name, command)
    for name, command in COMMANDS
    if command.request_cls.__module__ == "pipeline.neural.config"
    and any(isinstance(p, click.Argument) for p in command.params)
]


def _bad_folder(name, command, tmp_path):
    """``name`` with each operand a folder that holds no dataset, run or report, the required
    options valid (train's --out too): the folder, and the result."""
    folder = tmp_path / "not-a-dataset"
    folder.mkdir(exist_ok=True)
    operands = [str(folder) for p in command.params if isinstance(p, click.Argument)]
    options = valid_args(command, tmp_path)[len(_arguments(command)) :]
    if name == "train":
        options += ["--out", str(tmp_path / "run")]
    return folder, invoke(*name.split(), *operands, *options)


def _arguments(command):
    return [p for p in command.params if isinstance(p, click.Argument) and p.required]


@pytest.mark.parametrize("name, command", NEURAL_OPERANDS, ids=[n for n, _ in NEURAL_OPERANDS])
def test_a_bad_folder_is_named_in_double_quotes(name, command, tmp_path):
    folder, result = _bad_folder(name, command, tmp_path)
    assert result.exit_code == 2, result.output
    line = result.stderr.strip().splitlines()[-1]
    assert line.startswith("error: ") and json.dumps(str(folder)) in line, line
    assert not MINORITY["a single-quoted word"].search(line), line


def test_one_quoting_style_and_one_wording(tmp_path):
    found = [
        f"{where}: {what}: {m.group(0)!s}"
        for where, text in _texts(tmp_path)
        for what, pattern in MINORITY.items()
        for m in pattern.finditer(text)
    ]
    assert not found, found


# ----------------------------------------------------------------------------- help texts


@pytest.mark.parametrize("name, command", COMMANDS)
def test_help_says_what_is_allowed_before_the_default(name, command):
    """One order for every option, generated in one place (pipeline.ui.options.option_help):
    text, ``Allowed: ...``, then ``[default: ...]`` or ``[required ...]``."""
    ctx = click.Context(command, info_name=name)
    for option in command.params:
        record = option.get_help_record(ctx) if isinstance(option, click.Option) and not option.hidden else None
        if record and "Allowed:" in record[1]:
            before = record[1].split("Allowed:")[0]
            assert not re.search(r"\[(default|required)\b", before), f"{name} {option.opts[0]}: {record[1]}"


@pytest.mark.parametrize("group_name, group", GROUPS[1:])
def test_a_group_names_its_command_word_alike_in_usage_and_text(group_name, group):
    """`neural-bench`'s usage said COMMAND and its text KIND."""
    word = group.subcommand_metavar.split()[0]
    text = group.help or ""
    assert word in text and (word == "COMMAND" or "COMMAND" not in text), (word, text)
    usage = invoke(group_name, "--help").output.splitlines()[0]
    assert f" {word} [ARGS]..." in usage, usage


# ----------------------------------------------------------------------------- a closed stdout


def _closed_stdout_run(*args: str) -> subprocess.CompletedProcess:
    """`python -m cli ARGS` writing into a real pipe whose reader has already gone (as
    `| head -1` leaves one once it has its line: closed before the command writes, so the
    outcome does not depend on timing)."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        return subprocess.run(
            [sys.executable, "-m", "cli", *args], stdout=write_end, stderr=subprocess.PIPE, text=True, cwd=REPO
        )
    finally:
        os.close(write_end)


@pytest.mark.parametrize(
    "args",
    [["info", SMOKE], ["info", SMOKE, "--json"], ["plan", "--help"], ["--help"], ["neural-bench", "--help"]],
    ids=lambda a: " ".join(Path(w).name for w in a),
)
def test_a_closed_stdout_ends_the_command_quietly(args):
    """Exit status 141 (128 + SIGPIPE, as a shell reports for a Unix tool that SIGPIPE ends),
    nothing on stderr (it was ``error: ?: Broken pipe``, exit 4)."""
    done = _closed_stdout_run(*args)
    assert (done.returncode, done.stderr) == (141, ""), (done.returncode, done.stderr[-2000:])


def test_a_refusal_into_a_closed_stdout_keeps_its_message_and_code():
    done = _closed_stdout_run("info", "/nonexistent/x", "--json")
    assert done.returncode == 2, done.stderr
    assert done.stderr.startswith("error: DIR|SPEC: ") and "Broken pipe" not in done.stderr, done.stderr


# ----------------------------------------------------------------------------- docs/build.md


def test_build_page_names_what_two_builds_differ_in():
    """docs/build.md said two builds' records, markers and manifests are equal key for key;
    they differ in each render's wall time (docs/manifest.md): the page names every
    run-dependent key the code drops before comparing."""
    from pipeline.store.records import RUN_DEPENDENT_STATS

    text = " ".join((REPO / "docs" / "build.md").read_text().split())
    sentence = next(s for s in re.split(r"(?<=\.) ", text) if "records, markers and manifests" in s)
    assert "key for key" not in sentence or "but for" in sentence, sentence
    for key in RUN_DEPENDENT_STATS:
        assert f"`stats.{key}`" in sentence, sentence
