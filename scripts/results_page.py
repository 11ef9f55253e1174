"""The head of a generated results page (docs/results/): the command that wrote it, the date and
the machine, so a number quoted from it can be traced and re-measured.

    from scripts.results_page import head
    text = head("Title", ".venv/bin/python scripts/x.py --write") + body
"""

from __future__ import annotations

import datetime
import os
import platform
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from pipeline.render.mitsuba_env import cpu_model  # noqa: E402


def machine() -> str:
    """CPU model and count, system, Python version: what a measurement on this machine depends on."""
    system = f"{platform.system()} {platform.release()} {platform.machine()}"
    return f"{cpu_model()} ({os.cpu_count()} CPUs), {system}, Python {platform.python_version()}"


def write_flag(argv: list[str], script: str) -> bool:
    """Whether ``argv`` (a page script's arguments) asks for ``--write``; any other argument ends
    the script with exit 2 and its usage, before anything runs or is written."""
    if set(argv) - {"--write"}:
        print(f"error: unknown arguments: {' '.join(argv)}\nusage: scripts/{script} [--write]", file=sys.stderr)
        sys.exit(2)
    return "--write" in argv


def head(title: str, command: str) -> str:
    date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return f"# {title}\n\nWritten by `{command}` on {date}.\n\nMachine: {machine()}.\n\n"
