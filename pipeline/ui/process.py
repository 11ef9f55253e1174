"""How a `shaderball` command runs as a process: what it prints on success and failure, the
exit code of each way it ends, Ctrl-C, and stdout kept for the one JSON document of --json.

- A user error (:data:`pipeline.errors.USER_ERRORS`) is ``error: ...`` on stderr and its exit
  code (2, or the error's own: 1 refused, 3 busy, 4 file system); an OSError the library did
  not name is one line and exit code 4; Ctrl-C is one line saying how to go on, exit code 130.
  No traceback for any of them.
- A command refused before its body runs (a missing operand or option, an unknown option or
  command, an extra operand: click's refusals, in the project's form) is the same: ``error:
  OPT: ...`` on stderr, exit code 2 (:func:`refuse`).
- A stdout whose reader has gone (``shaderball plan SPEC | head -1``) ends the command quietly,
  as a Unix tool that SIGPIPE ends: nothing on stderr, exit status 141 (:func:`end_quietly`).
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
import select
import signal
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


#: Exit status of a command whose stdout's reader went away before it was done writing: 128 +
#: SIGPIPE, the status a shell reports for a Unix tool that the signal ended (`yes | head -1`).
PIPE_CLOSED_EXIT = 128 + signal.SIGPIPE


def emit_json(doc: dict) -> None:
    """The document a --json command prints on stdout once it returns (:func:`run_command`)."""
    click.get_current_context().meta[_JSON_DOC] = doc


def write_json(doc: dict, code: int = 0) -> None:
    """Print ``doc`` on stdout; if stdout's reader has gone, end quietly with ``code`` (a
    refusal's own) or, for a result no one reads, :data:`PIPE_CLOSED_EXIT`."""
    try:
        click.echo(json.dumps(doc, indent=1, sort_keys=True))
    except BrokenPipeError as exc:
        if not stdout_closed(exc):
            raise
        end_quietly(code or PIPE_CLOSED_EXIT)


def failure_doc(code: int, error: str, **extra) -> dict:
    return {"ok": False, "exit": code, "error": error, **extra}


def refuse(exc: BaseException, as_json: bool):
    """End a command refused before its body ran (a user error, or click's own refusal in the
    project's words: :func:`pipeline.ui.command.usage_refusal`): ``error: ...`` on stderr,
    with --json the failure document on stdout, the error's exit code (2)."""
    code = getattr(exc, "exit_code", 2)
    click.echo(f"error: {exc}", err=True)
    if as_json:
        extra = exc.to_dict() if hasattr(exc, "to_dict") else {}
        write_json(failure_doc(code, str(exc), **extra), code)
    sys.exit(code)


def stdout_closed(exc: BaseException) -> bool:
    """Whether ``exc`` is the failed write of a stdout whose reader has gone: a BrokenPipeError
    while file descriptor 1 is a pipe with no reader left (poll says POLLERR), not a socket
    of the library's that a peer closed."""
    if not isinstance(exc, BrokenPipeError):
        return False
    try:
        poller = select.poll()
        poller.register(1, select.POLLOUT)
        return any(events & (select.POLLERR | select.POLLHUP) for _, events in poller.poll(0))
    except (AttributeError, OSError, ValueError):  # no poll(): the broken pipe is taken as stdout's
        return True


def end_quietly(code: int = PIPE_CLOSED_EXIT):
    """End a command whose stdout's reader has gone, as Python's docs advise for SIGPIPE (the
    signal module, "Note on SIGPIPE"): stdout pointed at /dev/null, so that what is left in
    its buffer goes nowhere at exit instead of failing again, then exit, with no message: a
    reader that stopped reading (`head -1`) wanted no more. Exit status ``code``: 141, as a
    shell reports for a Unix tool that SIGPIPE ended, unless the command had failed already."""
    with contextlib.suppress(AttributeError, OSError, ValueError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    sys.exit(code)


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
    closed = False
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
            if stdout_closed(exc):  # ended below, once fd 1 is stdout again
                code, closed = PIPE_CLOSED_EXIT, True
            else:
                code, failed, stopped = _reported(exc, as_json, reword)
    if closed:
        end_quietly()
    if as_json:
        doc = failed or ctx.meta.get(_JSON_DOC)
        if doc is None:
            doc = {"ok": code == 0, "exit": code, "error": None if code == 0 else "the command stopped with no result"}
        write_json(doc, code)
    if stopped is not None and _own_streams():
        _end_now(code)
    if code:
        sys.exit(code)


def _reported(exc: BaseException, as_json: bool, reword) -> tuple[int, dict, Stopped | None]:
    """The exit code, failure document and Ctrl-C stop of an exception that ended a command,
    its message printed on stderr."""
    if reword is not None and isinstance(exc, USER_ERRORS):
        exc = reword(exc)
    code, message, extra = _failure(exc, as_json)
    click.echo(f"error: {message}" if code != INTERRUPTED_EXIT else message, err=True)
    return code, failure_doc(code, message, **extra), exc if isinstance(exc, Stopped) else None


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
