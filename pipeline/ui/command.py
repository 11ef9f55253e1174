"""Commands generated from requests: each command's inputs are the fields of one checked
request class (:class:`pipeline.fields.Checked`), and the click command is made from it.

``@request_command(main, ValidateRequest)`` over ``def validate_cmd(request)`` makes
``shaderball validate``: one click parameter per declared field (an operand for a
``positional`` field, ``--name`` for the others, with the field's type, default, range,
unit and help), ``--json``, and the body's docstring as its help. The body is called with
the checked request and returns its result: an object with ``lines()`` (what is printed)
and ``to_dict()`` (the --json document; ``"ok"`` and ``"exit"`` are added), and an
``exit_code`` attribute where success is not 0 (validate's 1 for an invalid dataset).

The library names a refused field by its own name (``limit``); here it is spelled as the
command line spells it (``--limit``, or ``DIR`` for an operand), in every refusal: a value
refused while parsing, a rule between fields, a check deep in the library.

Spellings that exist only here: ``--json`` (a flag), an option renamed in the past
(hidden; given, it exits 2 naming the new one), and a value given to ``--json``
(``--json=FILE``, ``--json FILE``: exit 2 naming ``--json-out`` where the command writes one).
click's own refusals (a missing operand, an unknown option, a word too many, an unknown
command) read as the fields' do (:mod:`pipeline.ui.usage`), with --json's document too.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.util
import inspect
import os
import shlex
import sys
from collections.abc import Callable

import click

from pipeline.errors import NEEDS_TORCH, USER_ERRORS, ShaderballError
from pipeline.fields import FIELD_REF, FieldError, default_of, flattened, parts
from pipeline.fields.rules import MISSING, AsTyped, Bool, Many, Optional
from pipeline.ui import process
from pipeline.ui.options import FieldType, option_help
from pipeline.ui.usage import ExtraOperands, unknown_command, usage_refusal


def option_name(name: str) -> str:
    """A field's spelling on the command line: ``loader_workers`` is ``--loader-workers``."""
    return "--" + name.replace("_", "-")


def _fields(request_cls) -> dict:
    """``request_cls``'s fields and its parts', by name (pipeline.fields.flattened): a part's
    fields are options of the command as the request's own are, spelled by their own names."""
    return {name: f for name, (f, _) in flattened(request_cls).items()}


def label_for(request_cls):
    """How the command line spells ``request_cls``'s fields: an operand by its metavar."""
    fields = _fields(request_cls)

    def label(name: str) -> str:
        f = fields.get(name)
        if f is not None and f.metadata.get("positional"):
            return _metavar(f)
        return option_name(name)

    label.names = set(fields)
    return label


def _metavar(f) -> str:
    return f.metadata.get("metavar") or f.name.upper()


class Operand(click.Argument):
    """An operand named by its field's metavar (``DIR``), shown in usage lines as click shows
    its own: ``[SPEC]`` where it may be left out, ``REPORT.json...`` where it repeats."""

    def make_metavar(self, ctx) -> str:
        var = self.metavar
        if not self.required and not var.startswith("["):
            var = f"[{var}]"
        if self.nargs != 1 and not var.endswith("..."):
            var += "..."
        return var


def _argument(f) -> click.Argument:
    rule = f.metadata["rule"]
    default = default_of(f)
    kwargs = dict(type=FieldType(rule), metavar=_metavar(f))
    if isinstance(rule, Many):  # each word checked by the item's rule, the whole by the field's
        kwargs.update(type=FieldType(rule.item), nargs=-1, required=True)
    elif default is not MISSING and default is not None:
        kwargs.update(required=False, default=default)
    elif isinstance(rule, Optional):
        kwargs.update(required=False, default=None)
    return Operand([f.name], **kwargs)


def _spelled(text: str, label) -> str:
    """``{field}`` in a help text spelled as the command line spells that field (only the
    request's own fields: other braces are text)."""
    return FIELD_REF.sub(lambda m: label(m.group(1)) if m.group(1) in label.names else m.group(0), text)


def _option(f, label) -> click.Option:
    rule = f.metadata["rule"]
    default = default_of(f)
    spelled = option_name(f.name)
    required = default is MISSING
    if isinstance(rule, Bool):
        decl = f"{spelled}/--no-{f.name.replace('_', '-')}" if default else spelled
        kwargs = dict(is_flag=True, default=bool(default), show_default=bool(default))
    elif isinstance(rule, Many):  # an option given again for each value: --object A --object B
        decl = spelled
        kwargs = dict(type=FieldType(rule.item), multiple=True, default=default, show_default=False)
        if f.metadata.get("metavar"):
            kwargs["metavar"] = f.metadata["metavar"]
    else:
        decl = spelled
        if isinstance(default, tuple):  # as it is typed: "0.5,0.5,0.5", "1,2,4"; () as the rule's word for none
            inner = rule.rule if isinstance(rule, Optional) else rule
            default = (
                ",".join(v if isinstance(v, str) else f"{v:g}" for v in default)
                if default
                else getattr(inner, "none", None) or ""
            )
        kwargs = dict(type=FieldType(rule), required=required, show_default=not required and default is not None)
        if not required:  # a required one has none: click refuses it missing (pipeline.ui.usage)
            kwargs["default"] = default
        if f.metadata.get("metavar"):
            kwargs["metavar"] = f.metadata["metavar"]
    kwargs["help"] = _spelled(option_help(f), label)
    return click.Option([decl, f.name], **kwargs)


def params_of(request_cls, skip=()) -> list[click.Parameter]:
    """The click parameters of ``request_cls``'s declared fields, in declaration order:
    operands first (as usage lines list them), then options."""
    fields = [f for f in _fields(request_cls).values() if f.name not in skip]
    label = label_for(request_cls)
    operands = [_argument(f) for f in fields if f.metadata.get("positional")]
    options = [_option(f, label) for f in fields if not f.metadata.get("positional")]
    return [*operands, *options]


def command_line(words: str, request, *, every: bool = False, skip: tuple[str, ...] = ()) -> str:
    """``request`` as the command line that makes it (a report's heading: the same command
    again): ``shaderball WORDS``, its operands, then each option not at its default, or with
    ``every`` each one that is set (a flag where it is not its default); ``skip``: fields the
    command line does not set."""
    argv, options = ["shaderball", *words.split()], []
    for f, path in flattened(type(request)).values():
        holder = functools.reduce(getattr, path, request)
        value, default = getattr(holder, f.name), default_of(f)
        if f.name in skip:
            continue
        if f.metadata.get("positional"):
            argv += list(value) if isinstance(value, tuple) else [value]
            continue
        if value is None or value == default and (not every or isinstance(value, bool)):
            continue
        spelled = option_name(f.name)
        if isinstance(value, bool):
            options.append(spelled if value else spelled.replace("--", "--no-", 1))
        elif isinstance(value, tuple):
            options += [spelled, ",".join(map(str, value)) or getattr(f.metadata["rule"], "none", "")]
        else:
            options += [spelled, str(value)]
    return shlex.join([*map(str, argv), *options])


def renamed_option(old: str, new: str, why: str = "", *, takes_value: bool = True) -> click.Option:
    """An old spelling of an option, hidden: given, it exits 2 naming the new one."""

    def refuse(ctx, param, value):
        if value is not None and value is not False:
            raise click.UsageError(f"{old}: renamed; use {new}" + (f" ({why})" if why else ""), ctx)

    return click.Option(
        [old, "renamed_" + old.lstrip("-").replace("-", "_")],  # its own name: the new option may take the old one's
        default=None,
        hidden=True,
        expose_value=False,
        is_flag=not takes_value,
        callback=refuse,
        is_eager=True,
    )


JSON_HELP = "Print the result as one JSON document on stdout (progress stays on stderr)."


def json_option(help: str = JSON_HELP) -> click.Option:
    """``--json``, a flag (``as_json``): one JSON document on stdout (:mod:`pipeline.ui.process`)."""
    return click.Option(["--json", "as_json"], is_flag=True, help=help)


def result_doc(result) -> dict:
    if result is None:
        return {}
    if hasattr(result, "to_dict"):
        return dict(result.to_dict())
    if dataclasses.is_dataclass(result):
        return dataclasses.asdict(result)
    return dict(result.__dict__)


def show_result(result, as_json: bool) -> int:
    """Print ``result`` (its lines, or with --json its document with ``ok`` and ``exit``);
    its exit code."""
    code = int(getattr(result, "exit_code", 0) or 0)
    if as_json:
        doc = result_doc(result)
        doc.setdefault("ok", code == 0)
        doc["exit"] = code
        process.emit_json(doc)
    elif result is not None:
        for line in result.lines():
            click.echo(line)
    return code


#: click's refusal that is help, not an error (a group given no command): shown as click shows it.
_HELP_ERRORS = tuple(
    getattr(click.exceptions, name) for name in ("NoArgsIsHelpError",) if hasattr(click.exceptions, name)
)


class _Refusing:
    """Every refusal of the command line in the project's one form (:mod:`pipeline.ui.usage`),
    printed by :func:`pipeline.ui.process.refuse`: ``error: OPT: ...`` on stderr, exit code
    2, and with --json the failure document on stdout. Help that a closed stdout cut short
    ends quietly (:func:`pipeline.ui.process.end_quietly`)."""

    def _json_wanted(self, args) -> bool:
        return process.wants_json(list(args))

    def make_context(self, info_name, args, parent=None, **extra):
        as_json = self._json_wanted(args)
        try:
            self._before_parsing(info_name, list(args), parent)
            return super().make_context(info_name, args, parent=parent, **extra)
        except _HELP_ERRORS:
            raise
        except click.ClickException as exc:
            process.refuse(usage_refusal(exc, self), as_json)
        except USER_ERRORS as exc:  # an option's value refused by its declaration
            process.refuse(exc, as_json)
        except BrokenPipeError as exc:  # --help, --version into a closed pipe
            if not process.stdout_closed(exc):
                raise
            process.end_quietly()

    def _before_parsing(self, info_name, args: list[str], parent) -> None:
        """A refusal of ``args`` before click parses them (none here)."""


class Command(_Refusing, click.Command):
    """A command whose every refusal reads in the project's form, and whose --json holds for
    them too (a bad option value, a missing operand, an unknown option, a word too many:
    click refuses them before the command runs): stdout gets the failure document, stderr the
    message, exit code 2."""

    allow_extra_args = True  # words left over are refused by parse_args, in the project's words

    def _json_wanted(self, args) -> bool:
        return any(p.name == "as_json" for p in self.params) and process.wants_json(list(args))

    def _before_parsing(self, info_name, args: list[str], parent) -> None:
        _refuse_json_with_a_value(self, info_name, args, parent)

    def parse_args(self, ctx, args):
        given = list(args)  # click consumes ``args`` while parsing
        rest = super().parse_args(ctx, args)
        if rest and not ctx.resilient_parsing:
            head = given[: given.index("--") if "--" in given else len(given)]
            after_json = [head[i + 1] for i, word in enumerate(head[:-1]) if word == "--json"]
            if rest[0] in after_json:  # ``--json out.json``: a value given to the flag, not an operand
                raise click.UsageError(_json_flag_message(self, f"--json {rest[0]}", rest[0]), ctx)
            raise ExtraOperands(rest, ctx)
        return rest


def _json_flag_message(command: click.Command, given: str, value: str = "") -> str:
    writes = any("--json-out" in getattr(p, "opts", ()) for p in command.params)
    value = value or "FILE"
    tail = f"write the file with --json-out {value}" if writes else f"keep the document with --json > {value}"
    return f"{given}: --json is a flag (one JSON document on stdout) and takes no value; {tail}"


def _refuse_json_with_a_value(command: click.Command, info_name, args: list[str], parent=None) -> None:
    """``--json=FILE``, or ``--json FILE.json`` (a JSON file's name after the flag, where the
    command takes no JSON file as an operand, or, where it does, a name that is no file: an
    output meant, not an input): a usage error naming ``--json-out``, before anything else
    is checked. The flag never takes the next word as its value."""
    head = args[: args.index("--") if "--" in args else len(args)]
    takes_json_files = any(
        isinstance(p, click.Argument) and ".json" in (p.metavar or "").lower() for p in command.params
    )
    for i, flag in enumerate(head):
        value = head[i + 1] if i + 1 < len(head) else ""
        given = None
        if flag.startswith("--json="):
            given, value = flag, flag.split("=", 1)[1]
        elif flag == "--json" and value and not value.startswith("-"):
            if takes_json_files and not os.path.lexists(value):
                given = f"--json {value}"
            elif not takes_json_files and value.lower().endswith(".json"):
                given = f"--json {value}"
        if given is not None:
            ctx = click.Context(command, info_name=info_name, parent=parent)
            raise click.UsageError(_json_flag_message(command, given, value), ctx)


class Group(_Refusing, click.Group):
    """A group whose refusals (an unknown command or option) read as every command's do."""

    command_class = Command

    def resolve_command(self, ctx, args):
        name = args[0] if args else ""
        as_json = process.wants_json(list(args))
        if name and not name.startswith("-") and not ctx.resilient_parsing and self.get_command(ctx, name) is None:
            process.refuse(unknown_command(self, ctx, name), as_json)
        try:
            return super().resolve_command(ctx, args)
        except click.ClickException as exc:
            process.refuse(usage_refusal(exc, self), as_json)

    def main(self, *args, **kwargs):
        try:
            return super().main(*args, **kwargs)
        finally:  # --help, --version, a usage error: no body ran to put Python's handler back
            process.loaded()


def as_typed(value):
    """A request's value as the command line types it: a tuple as ``1,2`` (``0.5,0.5,0.5``),
    not ``[1, 2]``; anything else as it is."""
    if not isinstance(value, (tuple, list)):
        return value
    return AsTyped(",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value))


def _part_classes(cls) -> list[type]:
    found = list(parts(cls).values())
    return found + [inner for part_cls in found for inner in _part_classes(part_cls)]


def reworded(request_cls):
    """A user error as the command line words it: a field of ``request_cls`` (or one it
    shares with a class that has no spelling of its own, or one of its parts') spelled as its
    option."""
    label = label_for(request_cls)
    names = set(flattened(request_cls))
    own = {request_cls, *_part_classes(request_cls)}

    def reword(exc):
        if not isinstance(exc, FieldError) or not exc.name or exc.name not in names:
            return exc
        owner = exc.owner
        if owner in own or (owner is not None and getattr(owner, "FIELD_PREFIX", "") == ""):
            return exc.labelled(label, as_typed(exc.value))
        return exc

    return reword


def request_of(request_cls, values: dict):
    """The request that the command line's parsed ``values`` make (checked as it is made),
    each part made from its own fields' values first."""
    own = dict(values)
    for name, part_cls in parts(request_cls).items():
        names = set(flattened(part_cls))
        own[name] = request_of(part_cls, {k: own.pop(k) for k in list(own) if k in names})
    return request_cls(**own)


def request_command(
    group: click.Group,
    request_cls,
    *,
    name: str | None = None,
    json: str | None = JSON_HELP,
    renamed: tuple[click.Option, ...] = (),
    skip: tuple[str, ...] = (),
    needs_torch: bool | Callable[[object], bool] = False,
):
    """Decorator: ``body(request)`` as a command of ``group`` whose parameters are
    ``request_cls``'s fields (module docstring). ``json``: --json's help (None: no --json);
    ``renamed``: hidden old spellings; ``skip``: fields the command line does not set;
    ``needs_torch``: the body runs the neural stage (True, or a function of the request:
    where it does), refused before the body runs where torch is not installed."""

    def decorate(body):
        params = params_of(request_cls, skip) + list(renamed)
        if json is not None:
            params.append(json_option(json))
        takes = set(inspect.signature(body).parameters)
        reword = reworded(request_cls)

        def callback(as_json: bool = False, **values):
            def call():
                request = request_of(request_cls, values)
                if needs_torch is True or callable(needs_torch) and needs_torch(request):
                    refuse_without_torch()
                given = {"as_json": as_json} if "as_json" in takes else {}
                code = show_result(body(request, **given), as_json)
                if code:
                    sys.exit(code)

            process.run_command(call, as_json, reword)

        command = Command(
            name or body.__name__.removesuffix("_cmd").replace("_", "-"),
            params=params,
            callback=callback,
            help=inspect.getdoc(body),
            context_settings=group.context_settings,
        )
        group.add_command(command)
        command.body = body
        command.request_cls = request_cls
        command.needs_torch = needs_torch
        return body

    return decorate


def refuse_without_torch() -> None:
    """The neural stage's commands need torch, an optional extra (``pip install -e '.[train]'``):
    refused, exit code 2, where it is not installed. Looked up, not imported: the body's own
    refusals (a bad path) still come before torch loads (seconds)."""
    try:
        found = importlib.util.find_spec("torch") is not None
    except (ImportError, ValueError):  # a finder that refuses it; ``sys.modules["torch"] = None``
        found = False
    if not found:
        raise ShaderballError(NEEDS_TORCH)
