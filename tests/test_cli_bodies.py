"""Every command's body is one call: its request handed to one library function, whose
result is printed (pipeline.ui.command.request_command); and the neural stage's commands are
refused by the decorator, before their body runs, where torch is not installed."""

from __future__ import annotations

import ast
import inspect
import subprocess
import sys
import textwrap
from pathlib import Path

import click
import pytest

import cli

REPO = Path(__file__).resolve().parents[1]


def _commands(group: click.Group, prefix: str = ""):
    for name, command in sorted(group.commands.items()):
        if isinstance(command, click.Group):
            yield from _commands(command, f"{prefix}{name} ")
        else:
            yield f"{prefix}{name}", command


COMMANDS = dict(_commands(cli.main))


def _one_call(body) -> str | None:
    """Why ``body`` is not ``return f(request, ...)`` (a docstring allowed), or None."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(body)))
    statements = tree.body[0].body
    if statements and isinstance(statements[0], ast.Expr) and isinstance(statements[0].value, ast.Constant):
        statements = statements[1:]
    if len(statements) != 1 or not isinstance(statements[0], ast.Return):
        return f"{len(statements)} statements"
    call = statements[0].value
    if not isinstance(call, ast.Call) or not isinstance(call.func, ast.Name):
        return "not a call of a library function"
    if not call.args or not (isinstance(call.args[0], ast.Name) and call.args[0].id == "request") or call.args[1:]:
        return "the request is not its one operand"
    if call.func.id not in vars(cli) or inspect.getmodule(vars(cli)[call.func.id]).__name__.startswith("pipeline.ui"):
        return f"{call.func.id} is not a library function cli.py imports"
    return None


@pytest.mark.parametrize("name", COMMANDS)
def test_every_command_body_is_one_call_with_its_request(name):
    body = COMMANDS[name].body
    assert _one_call(body) is None, f"shaderball {name}: {_one_call(body)}"
    imports = [
        n
        for n in ast.walk(ast.parse(textwrap.dedent(inspect.getsource(body))))
        if isinstance(n, (ast.Import, ast.ImportFrom))
    ]
    assert imports == [], f"shaderball {name} imports inside its body"


def test_cli_imports_nothing_of_the_neural_stage_but_its_torch_free_modules():
    imported = {
        node.module
        for node in ast.walk(ast.parse((REPO / "cli.py").read_text()))
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("pipeline.neural")
    }
    assert imported == {"pipeline.neural.command", "pipeline.neural.config"}


#: The neural stage's commands, each with operands that reach its body (its own checks need no torch).
NEURAL = {
    "train": ["train", "DATASET", "--out", "OUT/run"],
    "infer": ["infer", "RUN", "--out", "OUT/ball.exr"],
    "evaluate": ["evaluate", "RUN", "DATASET"],
    "export": ["export", "RUN", "--out", "OUT/net.pt"],
    "sweep": ["sweep", "REPORT", "--out", "OUT/sweep"],
    "serve": ["serve", "--run", "RUN", "--benchmark"],
    "neural-bench loaders": ["neural-bench", "loaders", "DATASET", "DATASET"],
    "neural-bench collate": ["neural-bench", "collate", "DATASET"],
    "neural-bench denoise": ["neural-bench", "denoise", "DATASET"],
    "neural-bench train-options": ["neural-bench", "train-options"],
    "study": ["study", "manifests/smoke.toml", "--downstream", "--out", "OUT/study"],  # --downstream trains
}

#: ``import torch`` fails, as where the `train` extra is not installed.
NO_TORCH = """
import sys
class NoTorch:
    def find_spec(self, name, path=None, target=None):
        if name == "torch" or name.startswith("torch."):
            raise ModuleNotFoundError("No module named 'torch'", name="torch")
sys.meta_path.insert(0, NoTorch())
sys.argv = ["shaderball", *sys.argv[1:]]
import cli
cli.main()
"""


def test_the_neural_commands_are_the_ones_that_need_torch():
    needing = {name for name, command in COMMANDS.items() if command.needs_torch}
    assert needing == set(NEURAL)


def test_the_pixel_study_needs_no_torch(tmp_path):
    """study without --downstream runs no network: its own refusal, not torch's."""
    words = ["study", "manifests/smoke.toml", "--out", str(tmp_path / "s"), "--reference-spp", "3"]
    done = subprocess.run(
        [sys.executable, "-c", NO_TORCH, *words], cwd=REPO, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 2 and "--reference-spp" in done.stderr and "torch" not in done.stderr, done.stderr


@pytest.mark.parametrize("name", sorted(NEURAL))
def test_a_neural_command_without_torch_is_refused(name, tmp_path):
    """exit 2 and the one message, on stderr and in --json's document."""
    words = [w.replace("OUT", str(tmp_path)) for w in NEURAL[name]]
    for word in ("DATASET", "RUN"):
        (tmp_path / word).mkdir(exist_ok=True)
    (tmp_path / "REPORT").write_text("{}")
    words = [str(tmp_path / w) if w in ("DATASET", "RUN", "REPORT") else w for w in words]
    done = subprocess.run(
        [sys.executable, "-c", NO_TORCH, *words, "--json"], cwd=REPO, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 2, done.stderr
    assert "error: the neural stage needs torch: pip install -e '.[train]'" in done.stderr
    assert '"exit": 2' in done.stdout and "needs torch" in done.stdout
