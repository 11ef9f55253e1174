"""The geometry package's error type.

Domain packages import nothing of ``pipeline``; :data:`pipeline.errors.USER_ERRORS`
lists this type so the CLI reports it like its own errors (a clear message, exit 2).
"""


class GeometryError(ValueError):
    """A refused geometry input: the message names the field, the value and what is allowed."""

    #: The exit code the CLI gives it (the same as pipeline.errors.ShaderballError).
    exit_code = 2
