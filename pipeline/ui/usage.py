"""click's own refusals of a command line, in the project's one form: ``OPT: what; what is
allowed`` (a :class:`pipeline.fields.FieldError`, exit code 2), as every other refusal.

click refuses some command lines before any value reaches a field's rule: an operand or a
required option left out, an option it does not know, an option given no value (or a flag
given one), a word too many, a command it does not know. :func:`usage_refusal` words each
the way a field's refusal reads (the option as it is typed, an operand by its metavar, the
value as typed, what is allowed: for a missing value, its field's rule), and keeps click's
"did you mean" where it has one. The command line (:mod:`pipeline.ui.command`) prints it as
it prints every refusal (:func:`pipeline.ui.process.refuse`).
"""

from __future__ import annotations

import difflib

import click

from pipeline.errors import ShaderballError
from pipeline.fields import FieldError, declared
from pipeline.fields.rules import MISSING, AsTyped, Many, format_value


class ExtraOperands(click.UsageError):
    """Words left over once a command's operands are taken (click's "unexpected extra argument")."""

    def __init__(self, words: list[str], ctx: click.Context):
        super().__init__(f"unexpected operand(s): {' '.join(words)}", ctx)
        self.words = list(words)


def usage_refusal(exc: click.ClickException, command: click.Command) -> ShaderballError:
    """``exc``, a refusal of click's, as the project's :class:`FieldError` (or, for a message
    already in the project's form, a :class:`ShaderballError` carrying it)."""
    ctx = getattr(exc, "ctx", None) or click.Context(command, info_name=command.name)
    if isinstance(exc, click.MissingParameter) and exc.param is not None:
        return missing(exc.param, ctx)
    if isinstance(exc, click.NoSuchOption):
        return unknown_option(exc.option_name, exc.possibilities or (), ctx)
    if isinstance(exc, click.BadOptionUsage):
        param = _option_named(ctx.command, exc.option_name)
        if param is not None and (param.is_flag or param.count):
            return FieldError(exc.option_name, None, f"write {exc.option_name} alone", what="a flag takes no value")
        if param is not None:
            return missing(param, ctx, where=exc.option_name)
    if isinstance(exc, ExtraOperands):
        return extra_operands(exc.words, ctx)
    if isinstance(exc, click.BadParameter) and exc.param is not None:
        return FieldError(_where(exc.param), None, exc.message, what="not allowed", name=exc.param.name or "")
    error = ShaderballError(exc.message if isinstance(exc, click.UsageError) else exc.format_message())
    error.exit_code = exc.exit_code
    return error


def _where(param: click.Parameter) -> str:
    """A parameter as the command line spells it: an option by its first spelling, an operand
    by its metavar (``DIR``)."""
    if isinstance(param, click.Argument):
        return param.metavar or param.name.upper()
    return param.opts[0]


def _option_named(command: click.Command, name: str) -> click.Option | None:
    for param in command.params:
        if isinstance(param, click.Option) and name in (*param.opts, *param.secondary_opts):
            return param
    return None


def _allowed(param: click.Parameter, ctx: click.Context) -> str:
    """What ``param`` takes: its field's rule's words (the request's declaration), else its
    type's."""
    request_cls = getattr(ctx.command, "request_cls", None)
    field = declared(request_cls).get(param.name) if request_cls is not None else None
    if field is not None:
        rule = field.metadata["rule"]
        return rule.item.allowed if isinstance(rule, Many) else rule.allowed
    rule = getattr(param.type, "rule", None)
    return rule.allowed if rule is not None else "a value"


def missing(param: click.Parameter, ctx: click.Context, where: str | None = None) -> FieldError:
    """``OPT: missing; <what is allowed>``: the one wording of a value left out, whether an
    operand, a required option, or an option typed with no value after it."""
    allowed = _allowed(param, ctx)
    if isinstance(param, click.Argument) and param.nargs != 1:
        allowed = "one or more: " + allowed
    return FieldError(where or _where(param), MISSING, allowed, what="missing", name=param.name or "")


def _one_of(names) -> str:
    names = list(names)
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " or " + names[-1]


def unknown_option(name: str, possibilities, ctx: click.Context) -> FieldError:
    """``--bogus: unknown option; `shaderball plan --help` lists them (did you mean --jobs?)``."""
    allowed = f"`{ctx.command_path} --help` lists them"
    if possibilities:
        allowed += f" (did you mean {_one_of(sorted(possibilities))}?)"
    return FieldError(name, AsTyped(name), allowed, what="unknown option")


def unknown_command(group: click.Group, ctx: click.Context, name: str) -> FieldError:
    """``COMMAND: "biuld" is not allowed; one of "bench", "build", ... (did you mean "build"?)``:
    the command's name refused as a choice's value is."""
    names = group.list_commands(ctx)
    allowed = "one of " + ", ".join(format_value(n) for n in names)
    close = difflib.get_close_matches(name, names)
    if close:
        allowed += f" (did you mean {_one_of([format_value(n) for n in close])}?)"
    metavar = group.subcommand_metavar or "COMMAND"
    return FieldError(metavar.split()[0], name, allowed)


def extra_operands(words: list[str], ctx: click.Context) -> FieldError:
    """``"extra": unexpected operand; `shaderball plan` takes SPEC``."""
    operands = [p.make_metavar(ctx) for p in ctx.command.params if isinstance(p, click.Argument)]
    takes = " ".join(operands) if operands else "no operand, options only"
    where = ", ".join(format_value(w) for w in words)
    what = "unexpected operand" + ("s" if len(words) > 1 else "")
    return FieldError(where, AsTyped(where), f"`{ctx.command_path}` takes {takes}", what=what)
