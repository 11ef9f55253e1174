"""The project's own error type: the CLI maps it to a clean message and exit code 2."""


class ShaderballError(Exception):
    """A user-facing error: bad input, a missing dependency, a refused operation.

    The message names the field or option, the value and what is allowed.
    """

    exit_code = 2


class SetupError(ShaderballError):
    """The environment cannot run Mitsuba (no usable libLLVM, unknown variant, ...)."""


def bad_value(field: str, value, allowed: str) -> ShaderballError:
    """The project's one wording of a refused value: field, value, what is allowed."""
    return ShaderballError(f"{field}: {value!r} is not allowed; allowed: {allowed}")
