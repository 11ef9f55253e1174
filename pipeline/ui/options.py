"""Click options generated from typed fields (``pipeline.fields``): a parameter is declared
once, in the dataclass that owns it, and the command line reads that declaration.

``options_from(TrainConfig, "epochs", "lr")`` makes ``--epochs`` and ``--lr`` with the
field's type, default and help (its text, then what it allows and its unit); the value is
checked by the field's rule while the command line is parsed, and a refusal reads as the
class's own, a :class:`pipeline.fields.FieldError`: ``error: --epochs: 0 is not allowed;
an integer from 1 to 100000`` (exit code 2, before anything runs). The command's parameter is the field's name,
so ``TrainConfig(**options)`` takes them as they come.
"""

from __future__ import annotations

import re

import click

from pipeline.fields import AsTyped, Bool, Choice, FieldError, Optional, Path, Reject, Rule, declared, default_of


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
            allowed = self.rule.allowed + (f" {exc.detail}" if exc.detail else "")
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


def option_from(cls, name: str, *, flag: str | None = None, unset: str | None = None, **changes) -> click.Option:
    """One click option of ``cls``'s field ``name``; ``flag`` spells a boolean's switch
    (``"--hash-check/--no-hash-check"``); ``unset``: the option defaults to None, which
    means this (``"the spec's"``); ``changes`` go to click.option as they are."""
    f = declared(cls)[name]
    rule = f.metadata["rule"]
    default = default_of(f)
    spelled = cls.field_label(name) if cls.FIELD_PREFIX == "--" else "--" + name.replace("_", "-")
    if isinstance(rule, Bool):
        decl = flag or (f"{spelled}/--no-{name.replace('_', '-')}" if default else spelled)
        kwargs = dict(is_flag=True, default=bool(default), show_default=bool(default) and "/" in decl)
    else:
        if isinstance(default, tuple):  # as it is typed: "0.5,0.5,0.5"
            default = ",".join(f"{v:g}" for v in default)
        kwargs = dict(type=FieldType(rule), default=default, show_default=default is not None)
        decl = spelled
    kwargs["help"] = option_help(f)
    if unset is not None:
        kwargs.update(default=None, show_default=False, help=f"{kwargs['help']} [default: {unset}]")
    kwargs.update(changes)
    return click.option(decl, name, **kwargs)


def options_from(cls, *names: str, **per_name: dict):
    """One decorator of the options of ``cls``'s fields ``names``, in that order (as
    --help lists them); ``per_name[name]`` holds :func:`option_from`'s keywords."""
    options = [option_from(cls, name, **per_name.get(name, {})) for name in names]

    def apply(func):
        for option in reversed(options):
            func = option(func)
        return func

    return apply
