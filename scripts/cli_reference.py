"""Write docs/cli.md, the command-line reference, from cli.py's own click objects.

    .venv/bin/python scripts/cli_reference.py            # print the page
    .venv/bin/python scripts/cli_reference.py --write    # replace docs/cli.md

Every command gets its usage line, a table of its options (name, type, default, help) and
the example its --help ends with. tests/test_cli_reference.py fails when docs/cli.md differs
from what this prints; tests/test_cli_examples.py reads the examples with
:func:`examples_in` and runs them.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
PAGE = REPO / "docs" / "cli.md"
PROG = "shaderball"
WRITE_COMMAND = "python scripts/cli_reference.py --write"

#: The heading of the last paragraph of every command's help.
EXAMPLE_HEADINGS = ("Example:", "Examples:")


def _paragraphs(text: str) -> list[list[str]]:
    """Non-empty lines grouped by blank lines; click's ``\\b`` (verbatim) markers dropped."""
    groups: list[list[str]] = [[]]
    for line in text.splitlines():
        if line.strip() in ("", "\b"):
            if line.strip() == "" and groups[-1]:
                groups.append([])
            continue
        groups[-1].append(line)
    return [g for g in groups if g]


def help_description(help_output: str) -> str:
    """The description part of a command's ``--help`` output: what follows the usage lines,
    up to the options table."""
    lines = help_output.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("Usage:"))
    end = next(i for i, line in enumerate(lines) if line.startswith("Options:"))
    body = lines[start + 1 : end]
    while body and body[0].startswith(" ") and body[0].strip():  # a usage line wrapped by click
        body = body[1:]
    return "\n".join(body)


def examples_in(description: str) -> list[str]:
    """The command lines of the last paragraph of a description (a docstring or the
    description part of --help), when that paragraph is an ``Example:`` block; else [].

    A line ending in a backslash continues on the next, as in a shell."""
    paragraphs = _paragraphs(description)
    if not paragraphs or paragraphs[-1][0].strip() not in EXAMPLE_HEADINGS:
        return []
    commands: list[str] = []
    pending = ""
    for line in paragraphs[-1][1:]:
        text = line.strip()
        if text.endswith("\\"):
            pending += text[:-1].rstrip() + " "
            continue
        commands.append(pending + text)
        pending = ""
    if pending:
        commands.append(pending.rstrip())
    return commands


def _context(command, name: str | None):
    import click

    from cli import main

    settings = {"terminal_width": 100, "max_content_width": 100}
    root = click.Context(main, info_name=PROG, **settings)
    return root if name is None else click.Context(command, info_name=name, parent=root, **settings)


def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def _option_row(option, ctx) -> str:
    import click

    names = ", ".join(f"`{n}`" for n in option.opts)
    if option.secondary_opts:
        names += " / " + ", ".join(f"`{n}`" for n in option.secondary_opts)
    if option.is_flag:
        kind = "flag"
    elif isinstance(option.type, click.Choice):
        kind = "|".join(map(str, option.type.choices))
    else:
        kind = option.make_metavar(ctx)
    value = option.get_default(ctx, call=False)
    if option.required:
        default = "required"
    elif option.is_flag and option.secondary_opts:
        default = f"`{option.opts[0] if value else option.secondary_opts[0]}`"
    elif option.is_flag:
        default = "on" if value else "off"
    elif value is None or callable(value):
        default = ""
    else:
        default = f"`{value}`"
    return f"| {names} | {_cell(kind)} | {_cell(default)} | {_cell(option.help or '')} |"


def _section(command, name: str | None) -> list[str]:
    import click

    ctx = _context(command, name)
    title = PROG if name is None else f"{PROG} {name}"
    paragraphs = _paragraphs(command.help or "")
    examples = examples_in(command.help or "")
    if examples:
        paragraphs = paragraphs[:-1]
    out = [f"## {title}", ""]
    for paragraph in paragraphs:
        out += [" ".join(line.strip() for line in paragraph), ""]
    out += ["```text", command.get_usage(ctx), "```", ""]
    options = [
        p for p in command.get_params(ctx) if isinstance(p, click.Option) and not p.hidden and "--help" not in p.opts
    ]
    out += ["| option | type | default | help |", "|---|---|---|---|"]
    out += [_option_row(option, ctx) for option in options]
    out.append("")
    if examples:
        out += ["Example:" if len(examples) == 1 else "Examples:", "", "```sh", *examples, "```", ""]
    return out


def command_names() -> list[str]:
    """Every command of the group, in the order ``shaderball --help`` lists them; a command group
    (``neural-bench``) is followed by its subcommands, named ``"neural-bench loaders"``."""
    import click

    from cli import main

    names = []
    for name in main.list_commands(_context(main, None)):
        names.append(name)
        group = main.commands[name]
        if isinstance(group, click.Group):
            names += [f"{name} {sub}" for sub in group.list_commands(_context(group, name))]
    return names


def command_for(name: str):
    """The click command of a name from ``command_names()``."""
    from cli import main

    command = main
    for word in name.split():
        command = command.commands[word]
    return command


def render() -> str:
    """The text of docs/cli.md."""
    from cli import main

    names = command_names()
    lines = [
        "# Command-line reference",
        "",
        f"Written by `{WRITE_COMMAND}` from cli.py's click commands; do not edit by hand",
        "(`tests/test_cli_reference.py` fails when this page is stale). `shaderball COMMAND --help` says the",
        "same. `tests/test_cli_examples.py` runs every example below, each command's after those whose output",
        "it reads: `demo-out/smoke` is `manifests/smoke.toml` built, `demo-out/smoke-pub` its publication,",
        "`runs/smoke` a network trained on it.",
        "",
        "Commands: " + ", ".join(f"[{n}](#{PROG}-{n.replace(' ', '-')})" for n in names) + ".",
        "",
    ]
    lines += _section(main, None)
    for name in names:
        lines += _section(command_for(name), name)
    return "\n".join(lines).rstrip("\n") + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Print or write docs/cli.md from cli.py's click commands.")
    parser.add_argument("--write", action="store_true", help=f"replace {PAGE.relative_to(REPO)}")
    args = parser.parse_args(argv)
    text = render()
    if args.write:
        PAGE.write_text(text)
        print(f"wrote {PAGE.relative_to(REPO)}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
