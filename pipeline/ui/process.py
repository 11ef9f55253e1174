"""How a `shaderball` command runs as a process: what it prints on success and failure, the
exit code of each way it ends, Ctrl-C, and stdout kept for the one JSON document of --json.

- A user error (:data:`pipeline.errors.USER_ERRORS`) is ``error: ...`` on stderr and its exit
  code (2, or the error's own: 1 refused, 3 busy, 4 file system); an OSError the library did
  not name is one line and exit code 4; Ctrl-C is one line saying how to go on, exit code 130.
  No traceback for any of them.
- With --json, stdout carries exactly one JSON document whatever happens: the command's
  result with ``"ok": true``, or ``{"ok": false, "exit": N, "error": "..."}`` (plus what a
  refusal adds: ``kind``, ``message``) for every failure, an internal error included (exit
  code 70, its traceback on stderr). Library output (OpenEXR's C++ warnings, Mitsuba's, a
  stray print) goes to stderr meanwhile: file descriptor 1 is pointed there.

The command line itself (cli.py) and the commands generated from requests
(:mod:`pipeline.ui.command`) use this; nothing here knows a command.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import sys
import traceback

import click

from pipeline.errors import USER_ERRORS, caused_by_interrupt, filesystem_error
from pipeline.ui.interrupt import INTERRUPTED_EXIT, INTERRUPTED_MESSAGE, Stopped, loaded, wants_json

#: Exit code of an internal error (a bug; the traceback goes to stderr) under --json: sysexits.h's
#: EX_SOFTWARE. Without --json the traceback is Python's own (exit code 1).
INTERNAL_EXIT = 70
#: Where a --json command leaves its one document (click's context meta).
_JSON_DOC = "shaderball.json_doc"


def emit_json(doc: dict) -> None:
    """The document a --json command prints on stdout once it returns (:func:`run_command`)."""
    click.get_current_context().meta[_JSON_DOC] = doc


def write_json(doc: dict) -> None:
    click.echo(json.dumps(doc, indent=1, sort_keys=True))


def failure_doc(code: int, error: str, **extra) -> dict:
    return {"ok": False, "exit": code, "error": error, **extra}


@contextlib.contextmanager
def library_output_to_stderr(active: bool):
    """While a --json command runs, the process's file descriptor 1 is its stderr, so stdout
    then carries the command's one JSON document alone. Only where sys.stdout is fd 1
    (click's test runner replaces it with a buffer: nothing to redirect)."""
    try:
        fd = sys.stdout.fileno() if active else None
    except (AttributeError, OSError, ValueError):
        fd = None
    if fd != 1:
        yield
        return
    sys.stdout.flush()
    saved = os.dup(1)
    os.dup2(2, 1)
    try:
        yield
    finally:
        sys.stdout.flush()
        _flush_c_stdio()
        os.dup2(saved, 1)
        os.close(saved)


def _flush_c_stdio() -> None:
    """Flush C's stdio buffers (a library's printf) before fd 1 is given back."""
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):
        pass


def _failure(exc: BaseException, as_json: bool) -> tuple[int, str, dict]:
    """(exit code, one-line message, extra JSON fields) of an exception that ends a command;
    the exception itself is re-raised where the non-JSON CLI lets it through."""
    if isinstance(exc, USER_ERRORS):
        extra = exc.to_dict() if hasattr(exc, "to_dict") else {}  # a refusal's kind and message
        return getattr(exc, "exit_code", 2), str(exc), extra
    if isinstance(exc, click.ClickException):
        if not as_json:
            raise exc
        return exc.exit_code, exc.format_message(), {}
    if isinstance(exc, OSError):
        error = filesystem_error(exc, "?", "fix the cause and run the same command again")
        return error.exit_code, str(error), {}
    if caused_by_interrupt(exc):  # a KeyboardInterrupt, or what one caused (drjit's import, a plugin callback)
        click.echo("", err=True)
        return INTERRUPTED_EXIT, str(exc) if isinstance(exc, Stopped) else INTERRUPTED_MESSAGE, {}
    if not as_json or not isinstance(exc, Exception):
        raise exc
    click.echo("".join(traceback.format_exception(exc)).rstrip(), err=True)
    message = f"internal error (a bug; traceback on stderr): {type(exc).__name__}: {exc}"
    return INTERNAL_EXIT, " ".join(message.split())[:2000], {}


def _exit_code(code) -> int:
    if code is None:
        return 0
    return code if isinstance(code, int) else 1


def run_command(call, as_json: bool, reword=None) -> None:
    """Run ``call()`` as a command's body: every way it ends mapped to a message, a JSON
    document (with --json) and an exit code (module docstring). ``reword(exc)`` gives a
    user error the surface's spelling (a request's field as its option)."""
    ctx = click.get_current_context()
    failed = stopped = None
    loaded()  # Ctrl-C is a KeyboardInterrupt from here (pipeline.ui.interrupt before)
    with library_output_to_stderr(as_json):
        try:
            call()
            code = 0
        except SystemExit as exc:
            code = _exit_code(exc.code)
        except click.exceptions.Exit as exc:  # ctx.exit(N)
            code = exc.exit_code
        except BaseException as exc:  # noqa: BLE001 - mapped to a message; re-raised where it is a bug
            if reword is not None and isinstance(exc, USER_ERRORS):
                exc = reword(exc)
            code, message, extra = _failure(exc, as_json)
            click.echo(f"error: {message}" if code != INTERRUPTED_EXIT else message, err=True)
            failed = failure_doc(code, message, **extra)
            stopped = exc if isinstance(exc, Stopped) else None
    if as_json:
        doc = failed or ctx.meta.get(_JSON_DOC)
        if doc is None:
            doc = {"ok": code == 0, "exit": code, "error": None if code == 0 else "the command stopped with no result"}
        write_json(doc)
    if stopped is not None and _own_streams():
        _end_now(code)
    if code:
        sys.exit(code)


def _own_streams() -> bool:
    """Whether sys.stdout and sys.stderr are this process's file descriptors 1 and 2: the
    command runs as its own process (click's test runner swaps in buffers, and reads the exit
    code from SystemExit)."""
    try:
        return sys.stdout.fileno() == 1 and sys.stderr.fileno() == 2
    except (AttributeError, OSError, ValueError):
        return False


def _end_now(code: int) -> None:
    """End the process now, its output flushed, without interpreter shutdown: a command that
    answered Ctrl-C itself (:class:`pipeline.ui.interrupt.Stopped`) has nothing left to write,
    and may have left threads inside a native library, which shutdown would wait for or free
    what they use."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    _flush_c_stdio()
    os._exit(code)


__all__ = ["INTERRUPTED_EXIT", "INTERRUPTED_MESSAGE", "loaded", "wants_json"]
