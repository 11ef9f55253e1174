"""docs/cli.md is what scripts/cli_reference.py writes from cli.py's click commands now."""

from __future__ import annotations

from pathlib import Path

import click

from cli import main
from support.scripts import script_module

REPO = Path(__file__).resolve().parents[1]
cli_reference = script_module("cli_reference")


def test_docs_cli_md_is_the_generated_reference():
    written = (REPO / "docs" / "cli.md").read_text()
    assert written == cli_reference.render(), f"docs/cli.md is stale: run `{cli_reference.WRITE_COMMAND}`"


def test_the_reference_has_every_command_and_option():
    text = cli_reference.render()
    assert text.splitlines()[2].startswith(f"Written by `{cli_reference.WRITE_COMMAND}`")
    for name, command in main.commands.items():
        section = text.split(f"\n## shaderball {name}\n", 1)[1].split("\n## ", 1)[0]
        assert f"Usage: shaderball {name} " in section
        for option in (p for p in command.params if isinstance(p, click.Option) and not p.hidden):
            assert f"| `{option.opts[0]}`" in section, f"{name}: {option.opts[0]} missing from the reference"
        assert "```sh\nshaderball " + name in section, f"{name}: no example in the reference"
