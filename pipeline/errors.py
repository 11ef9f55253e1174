"""The project's error types: the CLI maps every one of them to a clean message and exit code 2.

The domain packages (``materials``, ``sky``, ``geometry``) import nothing of
``pipeline``, so each raises its own ``ValueError`` subclass; :data:`USER_ERRORS` is
the one list of every type that means "the user's input was refused". Code that
reports a user error catches ``USER_ERRORS``, never ``ShaderballError`` alone, so a
domain error reaches the user as the same clear message and exit code. How a command's result
is printed where it is not an error is here too (:class:`Printed`: its text, its --json
document, its exit code), so every layer of the library can return one.

Layer 2 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``materials``, ``sky``, ``geometry``; nothing else of the project.
"""

import errno
import json
import re

from geometry.errors import GeometryError
from materials.errors import MaterialError
from sky.errors import SkyError


class ShaderballError(Exception):
    """A user-facing error: bad input, a missing dependency, a refused operation.

    The message names the field or option, the value and what is allowed.
    """

    exit_code = 2


class SetupError(ShaderballError):
    """The environment cannot run Mitsuba (no usable libLLVM, unknown variant, ...)."""


class FolderBusy(ShaderballError):
    """Another writer (a build, ``validate --repair``, an unpack) holds the dataset folder.

    Exit code 3: nothing is wrong with the input; the same command succeeds once the other
    writer is done (pipeline.store.lock).
    """

    exit_code = 3


class FilesystemError(ShaderballError):
    """The operating system refused a read or write of the dataset (permission, full disk,
    name too long, ...). Exit code 4; every write is atomic, so the same command resumes
    once the cause is fixed."""

    exit_code = 4


def filesystem_error(exc: OSError, where: str, hint: str) -> FilesystemError:
    """The one-line message of an OSError met while writing ``where``: the path, the
    reason and its errno name, then ``hint`` (what to do next)."""
    name = errno.errorcode.get(exc.errno, str(exc.errno)) if exc.errno is not None else "?"
    path = exc.filename if exc.filename is not None else where
    return FilesystemError(f"{path}: {exc.strerror or exc} ({name}); {hint}")


#: The refusal of a command of the neural stage where torch is not installed (an optional extra).
NEEDS_TORCH = "the neural stage needs torch: pip install -e '.[train]'"


class Printed:
    """A command's result that is a document (its --json) and the text printed without --json;
    ``exit_code``: the command's exit code where success is not 0."""

    def __init__(self, doc: dict, text: str, exit_code: int = 0):
        self.doc, self.text, self.exit_code = doc, text, exit_code

    def to_dict(self) -> dict:
        return self.doc

    def lines(self) -> list[str]:
        return self.text.rstrip("\n").split("\n") if self.text else []


#: Every error type whose message is meant for the user (a clean message and its exit code at the CLI).
USER_ERRORS = (ShaderballError, MaterialError, SkyError, GeometryError)


def quoted(text) -> str:
    """A user's word (a path, a name) inside a message, in the project's one quoting style:
    double quotes, JSON's escapes for control characters (as pipeline.fields.format_value
    shows a refused string)."""
    return json.dumps(str(text), ensure_ascii=False)


def short_repr(value, limit: int = 60) -> str:
    """``value`` cut to ``limit`` characters, for messages that quote user data: a string (and
    the strings inside a list or table) in double quotes (:func:`quoted`), anything else as
    Python writes it."""
    if isinstance(value, str):
        text = quoted(value)
    elif isinstance(value, (list, tuple, dict)):
        try:
            text = json.dumps(value, ensure_ascii=False)
        except (TypeError, ValueError):
            text = repr(value)
    else:
        text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


#: The last line of a Python traceback of a KeyboardInterrupt, inside another error's message.
_INTERRUPT_LINE = re.compile(r"(?m)^\s*KeyboardInterrupt\b")


def caused_by_interrupt(exc: BaseException) -> bool:
    """Whether ``exc`` is, or was caused by, a KeyboardInterrupt.

    Ctrl-C can land inside a Python callback Mitsuba calls (the BSDF plugin); drjit then
    raises a RuntimeError whose cause is the KeyboardInterrupt, and Mitsuba's scene parser (a
    plugin's constructor, called by ``load_dict``) one whose message holds the callback's
    traceback, ending in a line ``KeyboardInterrupt``.
    """
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        if isinstance(exc, RuntimeError) and _INTERRUPT_LINE.search(str(exc)):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False
