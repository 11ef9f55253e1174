"""Commands the tests run as child processes, each in a session of its own (a signal sent to its
group reaches everything it started; the test kills or interrupts the group)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def cli(*args) -> list[str]:
    """`shaderball ARGS` as this interpreter runs it (``python -m cli``, from REPO)."""
    return [sys.executable, "-m", "cli", *map(str, args)]


def started(command: list[str], **popen) -> subprocess.Popen:
    """``command`` started from REPO in a session of its own, stdin closed, stdout and stderr
    piped as text; ``popen`` changes any of that (env, text=False, ...)."""
    options = dict(stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return subprocess.Popen(command, cwd=REPO, start_new_session=True, **{**options, **popen})


def has_mapped(pid: int, library: str) -> bool:
    """Whether process ``pid`` has a file whose path holds ``library`` mapped (False once it is gone)."""
    try:
        with open(f"/proc/{pid}/maps") as maps:
            return library in maps.read()
    except OSError:
        return False
