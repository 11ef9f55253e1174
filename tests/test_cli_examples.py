"""Every `--help` ends with an example, and every example runs as a user would paste it.

The examples are read from each command's own --help text (scripts/cli_reference.py's
parser), then run through `python -m cli` from the repository, in the order they need each
other (build before info, train before infer, publish before verify), in one fresh folder:
the paths they write (under demo-out/ and runs/) are moved into it; what they read from the
repository (manifests/) is read there. A command added without an example fails here.
"""

from __future__ import annotations

import os
import re
import select
import shlex
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
from click.testing import CliRunner

from cli import main
from support.scripts import script_module

REPO = Path(__file__).resolve().parents[1]
cli_reference = script_module("cli_reference")

#: The folders examples write into; each is a folder of the test's own.
OUTPUT_ROOTS = ("demo-out", "runs")
#: The folders of the repository examples may read (and so never write).
INPUT_ROOTS = ("manifests",)
#: The order in which the examples need each other's outputs; a command not named here runs
#: after all of these, so it finds every dataset, publication and run they made.
ORDER = (
    *("build", "info", "validate", "preview", "plan", "publish", "verify", "unpack"),
    *("scene", "render", "train", "infer", "evaluate", "serve", "bench", "study"),
)
GROUP = "shaderball"  # the group's own `shaderball --help`
EXAMPLE_TIMEOUT_S = 600
SERVER_START_S = 180


def commands_in_order() -> list[str]:
    names = cli_reference.command_names()
    first = [name for name in ORDER if name in names]
    return [*first, *sorted(set(names) - set(first)), GROUP]


def help_text(name: str) -> str:
    args = ["--help"] if name == GROUP else [*name.split(), "--help"]
    result = CliRunner().invoke(main, args, prog_name=GROUP)
    assert result.exit_code == 0, result.output
    return result.output


def examples(name: str) -> list[str]:
    return cli_reference.examples_in(cli_reference.help_description(help_text(name)))


def _is_path(word: str) -> bool:
    return not word.startswith("-") and ("/" in word or re.search(r"\.[A-Za-z]\w*$", word) is not None)


def command_line(example: str, root: Path) -> list[str]:
    """The example as `python -m cli ...` with its output paths moved under ``root``."""
    words = shlex.split(example)
    assert words[0] == "shaderball", f"{example!r}: an example starts with `shaderball`"
    argv = []
    for word in words[1:]:
        if word.split("/", 1)[0] in OUTPUT_ROOTS:
            argv.append(str(root / word))
        else:
            assert not _is_path(word) or (word.split("/", 1)[0] in INPUT_ROOTS and (REPO / word).exists()), (
                f"{example!r}: {word} is neither an input under {', '.join(INPUT_ROOTS)}/ nor an output "
                f"under {', '.join(OUTPUT_ROOTS)}/"
            )
            argv.append(word)
    return [sys.executable, "-m", "cli", *argv]


def _is_server(argv: list[str]) -> bool:
    return argv[3] == "serve" and "--benchmark" not in argv


def _env() -> dict:
    return dict(os.environ, PYTHONPATH=str(REPO))


def _run_server(argv: list[str]) -> tuple[int, str]:
    """A server example, short-lived: on a free port, until it says where it serves and answers
    its page there; then Ctrl-C, after which it must exit 130 saying it stopped (0 is reported then)."""
    proc = subprocess.Popen(
        [*argv, "--port", "0"], cwd=REPO, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    seen: list[str] = []
    try:
        deadline = time.monotonic() + SERVER_START_S
        url = None
        while url is None and time.monotonic() < deadline:
            ready, _, _ = select.select([proc.stderr], [], [], 1.0)
            if not ready:
                continue
            line = proc.stderr.readline()
            if not line:
                break
            seen.append(line)
            if line.startswith("serving http://"):
                url = line.split()[1]
        if url is None:
            proc.kill()
            out, err = proc.communicate(timeout=60)
            return proc.returncode or 1, "".join(seen) + err + out + "\n(no `serving http://...` line)"
        with urllib.request.urlopen(url, timeout=60) as reply:
            status = reply.status
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=120)
        stopped = proc.returncode == 130 and "stopped (Ctrl-C); served http://" in err
        code = 0 if status == 200 and stopped else proc.returncode or 1
        return code, f"GET {url}: {status}\n" + "".join(seen) + err + out
    finally:
        proc.kill()


class Workspace:
    """One fresh folder for every example; each distinct example runs once."""

    def __init__(self, root: Path):
        self.root = root
        self.done: dict[str, tuple[int, str, float]] = {}

    def run(self, example: str) -> tuple[int, str, float]:
        if example not in self.done:
            argv = command_line(example, self.root)
            start = time.monotonic()
            if _is_server(argv):
                code, output = _run_server(argv)
            else:
                result = subprocess.run(
                    argv, cwd=REPO, env=_env(), capture_output=True, text=True, timeout=EXAMPLE_TIMEOUT_S
                )
                code, output = result.returncode, result.stdout + result.stderr
            self.done[example] = (code, output, time.monotonic() - start)
        return self.done[example]

    def run_command(self, name: str) -> list[tuple[str, int, str]]:
        """``name``'s examples, after those of every command before it (what they may need)."""
        order = commands_in_order()
        for earlier in order[: order.index(name)]:
            for example in examples(earlier):
                code, output, _ = self.run(example)
                assert code == 0, f"needed first: `{example}` exited {code}\n{output}"
        return [(example, *self.run(example)[:2]) for example in examples(name)]


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> Workspace:
    """The fresh folder, with the smoke dataset built once by `build`'s own example."""
    space = Workspace(tmp_path_factory.mktemp("examples"))
    for example in examples("build"):
        space.run(example)
    return space


def test_the_parser_reads_the_last_paragraph_only():
    text = "Do a thing.\n\n\b\nExamples:\n  shaderball a --x 1 \\\n    --y 2\n  shaderball b\n"
    assert cli_reference.examples_in(text) == ["shaderball a --x 1 --y 2", "shaderball b"]
    assert cli_reference.examples_in(text + "\nA paragraph after the examples.\n") == []
    assert cli_reference.examples_in("Do a thing.\n\nExample: none here.\n") == []


@pytest.mark.parametrize("name", commands_in_order())
def test_every_help_ends_with_an_example(name):
    found = examples(name)
    assert found, (
        f"`shaderball {'' if name == GROUP else name + ' '}--help` must end with an example: a last docstring "
        "paragraph '\\b', 'Example:', then indented `shaderball ...` lines (tests/test_cli_examples.py runs them)"
    )
    for example in found:
        if name != GROUP:
            assert example.startswith(f"shaderball {name} "), example
        command_line(example, Path("/nowhere"))  # its paths: under INPUT_ROOTS or OUTPUT_ROOTS


@pytest.mark.slow
@pytest.mark.parametrize("name", commands_in_order())
def test_every_example_runs(workspace, name):
    ran = workspace.run_command(name)
    assert ran, f"{name}: no example to run"
    for example, code, output in ran:
        assert code == 0, f"`{example}` exited {code}\n{output}"
