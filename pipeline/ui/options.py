"""Click parameter types and help generated from typed fields (``pipeline.fields``): a
parameter is declared once, in the dataclass that owns it, and the command line reads that
declaration (:func:`pipeline.ui.command.params_of` makes a command's parameters with these).

A value is checked by its field's rule while the command line is parsed (:class:`FieldType`),
and a refusal reads as the class's own, a :class:`pipeline.fields.FieldError`: ``error:
--epochs: 0 is not allowed; an integer from 1 to 100000`` (exit code 2, before anything
runs); :func:`option_help` writes a field's help in one order for every option.
"""

from __future__ import annotations

import re

import click

from pipeline.fields import FieldError
from pipeline.fields.rules import AsTyped, Bool, Choice, Optional, Path, Reject, Rule


class FieldType(click.ParamType):
    """A command-line value parsed as the field's type and checked by its rule."""

    def __init__(self, rule: Rule):
        self.rule = rule
        inner = rule.rule if isinstance(rule, Optional) else rule
        self.name = inner.py_type.__name__ if not isinstance(inner, Choice) else "choice"
        self.inner = inner

    def get_metavar(self, param, ctx=None) -> str | None:
        if isinstance(self.inner, Choice):
            return "[" + "|".join(self.inner.options) + "]"
        if isinstance(self.inner, Path):
            return "PATH"
        return getattr(self.inner, "metavar", None) or {int: "INTEGER", float: "FLOAT"}.get(self.inner.py_type, "TEXT")

    def convert(self, value, param, ctx):
        if not isinstance(value, str):
            return value  # a default, or a value given from Python: the class checks it
        try:
            parsed = self.inner.parse(value)
        except ValueError:
            raise refused(param, ctx, value, self.rule.allowed) from None
        try:
            return self.rule.check(parsed)
        except Reject as exc:
            allowed = (exc.allowed or self.rule.allowed) + (f" {exc.detail}" if exc.detail else "")
            shown = parsed if isinstance(parsed, str) else AsTyped(value.strip())  # "0,1", not [0, 1]
            raise refused(param, ctx, shown, allowed, what=exc.what) from None


def refused(param, ctx, value, allowed: str, what: str | None = None) -> FieldError:
    """The refusal the dataclass itself would raise, naming the option as it is spelled:
    ``--epochs: 0 is not allowed; an integer from 1 to 100000`` (the command reports it as
    it reports every user error: ``error: ...``, exit code 2); an operand by its metavar."""
    where = param.metavar if isinstance(param, click.Argument) and param.metavar else param.opts[0]
    return FieldError(where, value, allowed, what=what, name=param.name)


#: A bracket that ends a field's help text ("[default: the dataset's]", "[required, except
#: with --benchmark]"): it goes after what is allowed, where click puts its own "[default: 30]".
_TRAILING_BRACKET = re.compile(r"\s*(\[(?:default|required)\b[^\]]*\])(\.?)\s*$")


def option_help(f) -> str:
    """The field's help, in one order for every option: its text, what it allows (with its
    unit), then its default or requirement in brackets."""
    rule, unit = f.metadata["rule"], f.metadata["unit"]
    text, brackets = f.metadata["doc"].rstrip(), []
    if match := _TRAILING_BRACKET.search(text):
        text, brackets = text[: match.start()] + match.group(2), [match.group(1)]
    inner = rule.rule if isinstance(rule, Optional) else rule
    if not isinstance(inner, (Bool, Choice, Path)):
        brief = rule.brief
        if unit:  # "degrees in [0, 90]", "1 to 65536 samples per pixel"
            brief = f"{unit} in {brief}" if brief[0] in "[(" else f"{brief} {unit}"
        text = f"{text} Allowed: {brief}."
    if isinstance(rule, Optional) and rule.default_text and not brackets and "[default:" not in text:
        brackets.append(f"[default: {rule.default_text}]")
    return " ".join([text, *brackets])
