"""Every request and settings class is checked when it is made.

- For every command (walked from ``cli.main``, a group's subcommands too), each field with a
  scalar rule given a value the rule refuses: the request built from Python raises the
  kernel's one refusal, a ``FieldError`` naming that field, and the command line refuses the
  same value with the same words but for how it spells the field.
- Every ``Checked`` class (the spec's sections, the renderer's settings, the cluster options,
  ...) refuses a bad value of each scalar field when it is built, not at a later ``check()``:
  no class keeps a ``check`` method of its own, and no ``check_fields`` is left to call.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
import pkgutil

import click
import pytest
from test_cli_usage import COMMANDS, SMOKE, invoke, refusal, valid_args

import pipeline
from pipeline.fields import Checked, FieldError, declared, flattened
from pipeline.fields.rules import Choice, Float, Int, Many, Optional, Path
from pipeline.ui.command import request_of


def _bad(rule) -> tuple[object, str] | None:
    """A value ``rule`` refuses, as Python holds it and as a command line types it; None for
    rules with no scalar value to refuse here (flags, lists)."""
    if isinstance(rule, Many):  # a repeated operand: one word refused
        bad = _bad(rule.item)
        return None if bad is None else ((bad[0],), bad[1])
    inner = rule.rule if isinstance(rule, Optional) else rule
    if isinstance(inner, Int):
        value = inner.hi + 1 if inner.hi + 1 not in inner.also else inner.lo - 1
        return value, str(value)
    if isinstance(inner, Float):
        return math.nan, "nan"
    if isinstance(inner, Choice):
        return "no-such-choice", "no-such-choice"
    if isinstance(inner, Path) and inner.exists is not None:
        return "/no/such/path/here", "/no/such/path/here"
    return None


def _tail(message: str) -> str:
    """A refusal's words after the field's name (``--spp: 0 is ...`` -> ``0 is ...``)."""
    return message.split(": ", 1)[1]


def _cases():
    for name, command in COMMANDS:
        on_the_line = {p.name for p in command.params}
        for f, _ in flattened(command.request_cls).values():  # its parts' fields too
            bad = _bad(f.metadata["rule"]) if f.name in on_the_line else None
            if bad is not None:
                yield pytest.param(name, command, f.name, *bad, id=f"{name}-{f.name}")


CASES = list(_cases())


def test_every_command_has_a_request_class_with_cases():
    covered = {case.values[0] for case in CASES}
    assert covered == {name for name, _ in COMMANDS}, "a command with no scalar field to refuse"


#: Arguments where the ones every command is given (valid_args) are not enough: a rule
#: between fields asks for more (bench with no spec, render's --out an .exr file).
MORE = {
    "bench": lambda tmp: [SMOKE],
    "render": lambda tmp: ["--out", str(tmp / "ball.exr")],
    "figures": lambda tmp: ["contact-sheet", "--out", str(tmp / "sheet.png")],
}


def _args(name, command, tmp_path, every_operand=False) -> list[str]:
    if name in MORE:
        return MORE[name](tmp_path)
    return valid_args(command, tmp_path, every_operand=every_operand)


@pytest.mark.parametrize("name, command, field, value, typed", CASES)
def test_python_and_the_command_line_refuse_a_value_alike(name, command, field, value, typed, tmp_path):
    args = _args(name, command, tmp_path)
    ctx = command.make_context(name, list(args), resilient_parsing=False)
    values = {k: v for k, v in ctx.params.items() if k != "as_json" and not k.startswith("renamed_")}
    request_of(command.request_cls, values)  # the valid arguments make a request
    with pytest.raises(FieldError) as info:
        request_of(command.request_cls, {**values, field: value})
    assert info.value.name == field, str(info.value)
    param = next(p for p in command.params if p.name == field)
    if isinstance(param, click.Argument):  # the operands come first, in order: replace this one's
        words = _args(name, command, tmp_path, every_operand=True)
        operands = [p for p in command.params if isinstance(p, click.Argument)]
        words[operands.index(param)] = typed
        where = param.metavar
    else:
        words, where = [*args, param.opts[0], typed], param.opts[0]
    message = refusal(invoke(*name.split(), *words))
    assert message.startswith(f"{where}: "), message
    assert _tail(message) == _tail(str(info.value)), (message, str(info.value))


def _all_checked() -> list[type]:
    for module in pkgutil.walk_packages(pipeline.__path__, "pipeline."):
        if ".neural" in module.name or module.name.endswith("__main__"):
            continue  # torch's stage: its request classes live in pipeline.neural.config
        importlib.import_module(module.name)
    importlib.import_module("pipeline.neural.config")
    seen, todo = [], list(Checked.__subclasses__())
    while todo:
        cls = todo.pop()
        if cls not in seen:
            seen.append(cls)
            todo += cls.__subclasses__()
    return sorted((c for c in seen if dataclasses.is_dataclass(c)), key=lambda c: c.__qualname__)


CHECKED = _all_checked()


@pytest.mark.parametrize("cls", CHECKED, ids=lambda c: c.__qualname__)
def test_no_class_keeps_a_check_to_call(cls):
    assert not hasattr(cls, "check"), f"{cls.__qualname__}.check: checked when made, nothing to call"
    assert not hasattr(cls, "check_fields"), cls.__qualname__


#: What a class with required fields and no command of its own is made with.
MADE = {
    "DatasetSection": dict(name="x", seed=0, materials=1),
    "NetworkPart": dict(run="."),
    "ProbeRequest": dict(renders=2),
    "DatasetChoice": dict(sample="m000000_l0"),
    "MaterialKind": dict(kind="uniform"),
    "SvbrdfChoice": dict(family="tiles"),
    "FrameRequest": dict(client="tab"),
    "UploadRequest": dict(client="tab", map="diffuse"),
    "ViewRequest": dict(client="tab", material={"kind": "uniform"}, light={}),
}


def _settings_cases():
    requests = {command.request_cls for _, command in COMMANDS}
    for cls in CHECKED:
        fields = declared(cls)
        if any(issubclass(request, cls) for request in requests):
            continue  # a command's request (or what one extends): the cases above build it
        made = MADE.get(cls.__qualname__, {})
        for f in fields.values():
            bad = _bad(f.metadata["rule"])
            if bad is not None:
                yield pytest.param(cls, made, f.name, bad[0], id=f"{cls.__qualname__}-{f.name}")


SETTINGS = list(_settings_cases())


def test_settings_classes_are_covered():
    names = {case.values[0].__qualname__ for case in SETTINGS}
    assert {"RenderSettings", "ClusterOptions", "DatasetSection", "StorageSection", "LightChoice"} <= names, names


@pytest.mark.parametrize("cls, made, field, value", SETTINGS)
def test_a_settings_class_refuses_a_bad_value_when_made(cls, made, field, value):
    cls(**made)  # its defaults (and MADE's values) make one
    with pytest.raises(FieldError) as info:
        cls(**{**made, field: value})
    assert info.value.name == field, str(info.value)
