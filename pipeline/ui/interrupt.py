"""Ctrl-C before a command's body runs: the first thing cli.py installs.

Standard library only (``os``, ``signal``, ``sys``: no ``json``, nothing of the project), so that
it is in place before numpy, click or Mitsuba is loaded (a second or more of imports that write
nothing), however cli.py is started: the ``shaderball`` console script imports cli.py, it does
not run it as ``__main__``. Ctrl-C then stops at once with the interrupted exit code and line,
and --json's one document, without the import's traceback; it does so until the command's body
starts (:func:`loaded`, called by :mod:`pipeline.ui.process`), click's parsing included, and
:mod:`pipeline.ui.process` handles Ctrl-C from there. A process the command spawns imports
cli.py too (as its parent's main module): it keeps the handler it had.
"""

from __future__ import annotations

import os
import signal
import sys

#: Exit code of a command stopped by Ctrl-C (SIGINT): 128 + 2, as shells report it.
INTERRUPTED_EXIT = 130
INTERRUPTED_MESSAGE = (
    "interrupted (Ctrl-C): every write is atomic, nothing is torn; run the same command again to resume"
)
#: --json's document for it, as pipeline.ui.process writes one (indent 1, keys sorted), spelled
#: out: the handler may run while the json module is half imported.
INTERRUPTED_DOC = '{\n "error": "%s",\n "exit": %d,\n "ok": false\n}\n' % (INTERRUPTED_MESSAGE, INTERRUPTED_EXIT)

#: The handler :func:`loaded` puts back, while :func:`stop_on_ctrl_c_while_loading`'s is in place.
_put_back: list = []


class Stopped(KeyboardInterrupt):
    """A Ctrl-C a command has answered in order and words itself (``shaderball serve``: what
    it served); exit code :data:`INTERRUPTED_EXIT`, the command's line instead of
    :data:`INTERRUPTED_MESSAGE`, whose advice (resume) fits commands that write.

    The process ends at once after the line (:mod:`pipeline.ui.process`), without interpreter
    shutdown: the command has nothing left to write, and shutdown must never run beside a
    thread inside a native library. ``left_running``: the threads the command did not wait for
    (a Mitsuba render is not cut short; it is abandoned)."""

    def __init__(self, message: str, left_running: tuple[str, ...] = ()):
        super().__init__(message)
        self.left_running = tuple(left_running)


def wants_json(args: list[str]) -> bool:
    """Whether ``--json`` is among the options (before a ``--``)."""
    head = args[: args.index("--") if "--" in args else len(args)]
    return any(a == "--json" or a.startswith("--json=") for a in head)


def _interrupted(signum, frame):
    os.write(2, f"\n{INTERRUPTED_MESSAGE}\n".encode())
    if wants_json(sys.argv[1:]):
        os.write(1, INTERRUPTED_DOC.encode())
    os._exit(INTERRUPTED_EXIT)


def stop_on_ctrl_c_while_loading() -> None:
    """From now until :func:`loaded`, Ctrl-C ends the process at once (module docstring). Not
    where SIGINT is ignored, nor outside the main thread (signals are the main thread's), nor in
    a process spawned by the command (a rank of `train --devices N`), which imports cli.py as its
    parent's main module and runs no command: its parent answers Ctrl-C."""
    spawned = sys.modules.get("multiprocessing.process")
    if _put_back or (spawned is not None and spawned.current_process().name != "MainProcess"):
        return
    try:
        previous = signal.getsignal(signal.SIGINT)
        if previous is signal.SIG_IGN:
            return
        signal.signal(signal.SIGINT, _interrupted)
    except ValueError:  # not the main thread
        return
    _put_back.append(signal.default_int_handler if previous is None else previous)


def loaded() -> None:
    """The command's body starts: the handler the process had (Python's own) is put back."""
    if not _put_back:
        return
    try:
        if signal.getsignal(signal.SIGINT) is _interrupted:
            signal.signal(signal.SIGINT, _put_back[0])
    except ValueError:  # not the main thread: the main thread puts it back
        return
    _put_back.clear()
