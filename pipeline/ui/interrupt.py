"""Ctrl-C before a command's imports are done: the first thing cli.py installs.

Standard library only, so that it is in place before numpy, click or Mitsuba is loaded
(a second or more of imports that write nothing): Ctrl-C then stops at once with the
interrupted exit code and line, and --json's one document, without the import's traceback.
Python's own handler is put back before the command runs (:mod:`pipeline.ui.process`
handles Ctrl-C from then on).
"""

from __future__ import annotations

import json
import os
import signal
import sys

#: Exit code of a command stopped by Ctrl-C (SIGINT): 128 + 2, as shells report it.
INTERRUPTED_EXIT = 130
INTERRUPTED_MESSAGE = (
    "interrupted (Ctrl-C): every write is atomic, nothing is torn; run the same command again to resume"
)


class Stopped(KeyboardInterrupt):
    """A Ctrl-C a command has answered in order and words itself (``shaderball serve``: what
    it served); exit code :data:`INTERRUPTED_EXIT`, the command's line instead of
    :data:`INTERRUPTED_MESSAGE`, whose advice (resume) fits commands that write."""


def wants_json(args: list[str]) -> bool:
    """Whether ``--json`` is among the options (before a ``--``)."""
    head = args[: args.index("--") if "--" in args else len(args)]
    return any(a == "--json" or a.startswith("--json=") for a in head)


def stop_on_ctrl_c_while_loading() -> None:
    def interrupted(signum, frame):
        os.write(2, f"\n{INTERRUPTED_MESSAGE}\n".encode())
        if wants_json(sys.argv[1:]):
            doc = {"error": INTERRUPTED_MESSAGE, "exit": INTERRUPTED_EXIT, "ok": False}
            os.write(1, (json.dumps(doc, indent=1, sort_keys=True) + "\n").encode())
        os._exit(INTERRUPTED_EXIT)

    signal.signal(signal.SIGINT, interrupted)
