"""Typed fields: each user-facing parameter declared once, with its type, default, range,
unit and one line of help, and checked in one place.

A checked dataclass (:class:`Checked`) declares each field with :func:`field`, whose
``rule`` (:class:`Int`, :class:`Float`, :class:`Pair`, :class:`Choice`, ...) normalises a
value or refuses it. Every consumer reads the same declaration: the spec's sections
(``pipeline.dataset.spec``, and docs/spec.md generated from them), the renderer's
settings (``pipeline.render.settings``), the commands' request types, and the command
line, whose options are generated from the fields (``pipeline.ui.options``): name, type,
default, help, and the same check with the same words.

A refused value raises :class:`FieldError`, a ``ShaderballError`` (exit code 2 at the
command line) whose message reads ``<field>: <value> is not allowed; <what is allowed>``;
a class names its fields its own way (a spec section as ``render.spp``, a command's
options as ``--spp``; :meth:`Checked.field_error`).

Own kernel rather than a library: typed-settings (attrs classes, click options, TOML
loading) or pydantic (fields with ranges and descriptions) would each add a dependency
(and pydantic a compiled core) to every layer that declares a field, for what is here a
few hundred lines, and neither words its refusals in the project's one form (field, value,
what is allowed) nor keeps the spec's TOML rules (``true`` is no integer, ``8.0`` no
count, a list of distinct names, a closed interval) without as much code again in
validators. The standard library's dataclasses carry the metadata; this module reads it.
It stands one layer above ``pipeline.errors``, so a refusal is a ``ShaderballError`` like
every other user error (exit code 2 at the command line).

Layer 3 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``pipeline.errors``; nothing else of the project.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import fields
from typing import Any, ClassVar

from pipeline.errors import ShaderballError
from pipeline.fields.rules import MISSING, Optional, Reject, Rule, format_value

#: ``{name}`` inside a refusal's words: another field of the same request, spelled by the
#: surface that reports it (``--cluster`` on the command line, ``cluster.kind`` in a spec).
FIELD_REF = re.compile(r"\{([a-z][a-z0-9_]*)\}")


class FieldError(ShaderballError):
    """A refused field value: ``<where>: <value> is not allowed; <allowed>``.

    The library names a field by its own name (``name``) and the class that declares it
    (``owner``); each surface words it its own way (:meth:`labelled`). ``what`` and
    ``allowed`` may name other fields of ``owner`` as ``{field}``, spelled the same way.
    """

    def __init__(
        self,
        where: str,
        value: Any,
        allowed: str,
        *,
        what: str | None = None,
        name: str = "",
        owner: type | None = None,
    ):
        self.where = where
        #: The field's own name (``spp``), however ``where`` spells it.
        self.name = name
        self.owner = owner
        self.value = value
        self.allowed = allowed
        self.what = what
        label = owner.field_label if owner is not None and hasattr(owner, "field_label") else (lambda n: n)
        super().__init__(self._words(where, label))

    def _words(self, where: str, label) -> str:
        names = set(flattened(self.owner)) if self.owner is not None and dataclasses.is_dataclass(self.owner) else None

        def spell(text: str) -> str:
            return FIELD_REF.sub(
                lambda m: label(m.group(1)) if names is None or m.group(1) in names else m.group(0), text
            )

        what = f"{format_value(self.value)} is not allowed" if self.what is None else spell(self.what)
        return f"{where}: {what}; {spell(self.allowed)}"

    def labelled(self, label, value: Any = MISSING) -> FieldError:
        """The same refusal with every field spelled by ``label(name)`` (a surface's words),
        and its value as that surface shows it where ``value`` is given (:class:`AsTyped`)."""
        error = FieldError(
            label(self.name) if self.name else self.where,
            self.value if value is MISSING else value,
            self.allowed,
            what=self.what,
            name=self.name,
            owner=self.owner,
        )
        error.args = (error._words(error.where, label),)
        return error


# --------------------------------------------------------------------------- declaration


def field(
    default: Any = MISSING,
    *,
    rule: Rule,
    doc: str,
    unit: str = "",
    factory: Any = None,
    doc_default: str | None = None,
    in_file: bool = True,
    kw_only: bool = False,
    positional: bool = False,
    metavar: str | None = None,
):
    """A dataclass field with its rule, one line (or more) of help, its unit.

    ``in_file=False``: a field of the type that a spec file does not hold (the renderer's
    ``sun`` and ``model`` come from other sections of the spec). ``positional``: a request's
    operand (``DIR`` of ``validate DIR``) rather than a named setting; ``metavar`` names
    the value in usage lines (``DIR``, ``SECONDS``).
    """
    meta = {
        "rule": rule,
        "doc": doc,
        "unit": unit,
        "doc_default": doc_default,
        "in_file": in_file,
        "positional": positional,
        "metavar": metavar,
    }
    extra = {"kw_only": True} if kw_only else {}
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=meta, **extra)
    if default is MISSING:
        return dataclasses.field(metadata=meta, **extra)
    return dataclasses.field(default=default, metadata=meta, **extra)


def same_as(cls, name: str, *, unset: str | None = None, **changes):
    """A field declared as ``cls``'s field ``name`` is (its rule, help, unit, default): one
    declaration, read by another class. ``unset``: the field is optional, default None,
    which means this (``"the spec's"``); ``changes`` replace keywords of :func:`field`."""
    f = declared(cls)[name]
    meta = dict(f.metadata)
    kwargs = dict(
        rule=meta["rule"],
        doc=meta["doc"],
        unit=meta["unit"],
        doc_default=meta["doc_default"],
        metavar=meta.get("metavar"),
    )
    default = default_of(f)
    if unset is not None:
        kwargs["rule"], default = Optional(meta["rule"], f"unset ({unset})", default_text=unset), None
    kwargs.update(changes)
    return field(changes.pop("default", default), **{k: v for k, v in kwargs.items() if k != "default"})


def part(cls, *, doc: str):
    """A field whose value is a whole :class:`Checked` class: a part that several requests
    share (a render's material and light, a build's cluster options, a trained network),
    declared once in ``cls`` and nested, not copied field by field. The part is given as an
    instance or a dict of its fields; left out, it is made from its defaults (a part with a
    required field is required). The command line spells its fields as options and operands
    of their own (``--workers``, not ``--cluster-options-workers``: the names of a request
    and its parts never clash, :func:`flattened` checks it)."""
    meta = {"part": cls, "doc": doc}
    if any(default_of(f) is MISSING for f in declared(cls).values()):
        return dataclasses.field(metadata=meta)
    return dataclasses.field(default_factory=cls, metadata=meta)


def parts(cls) -> dict[str, type]:
    """The fields of ``cls`` declared with :func:`part`, by name, and each one's class."""
    return {f.name: f.metadata["part"] for f in fields(cls) if "part" in f.metadata}


def flattened(cls, _path: tuple[str, ...] = ()) -> dict[str, tuple[dataclasses.Field, tuple[str, ...]]]:
    """Every declared field of ``cls`` and of its parts (their parts too), in declaration
    order, by name: the field and the path of parts that holds it (``("cluster_options",)``;
    ``()`` for ``cls``'s own). A name declared twice over a request and its parts is a
    TypeError: one name, one field."""
    out: dict[str, tuple[dataclasses.Field, tuple[str, ...]]] = {}
    for f in fields(cls):
        if "part" in f.metadata:
            inner = flattened(f.metadata["part"], (*_path, f.name))
        elif "rule" in f.metadata:
            inner = {f.name: (f, _path)}
        else:
            continue
        clash = set(inner) & set(out)
        if clash:
            raise TypeError(f"{cls.__name__}: {sorted(clash)} declared twice (a field and a part's)")
        out.update(inner)
    return out


def declared(cls) -> dict[str, dataclasses.Field]:
    """The fields of ``cls`` declared with :func:`field`, by name."""
    return {f.name: f for f in fields(cls) if "rule" in f.metadata}


def default_of(f: dataclasses.Field) -> Any:
    """A field's default (MISSING where it has none)."""
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return MISSING


class Checked:
    """Mixin of a dataclass: every instance is checked when it is made (``__post_init__``):
    each declared field by its rule, then the class's rules between fields
    (:meth:`check_cross`). A refused value raises :class:`FieldError` naming the field, the
    same refusal for a Python caller as for the command line; what takes an instance never
    checks it again. A subclass with a ``__post_init__`` of its own calls this one first."""

    #: How a refusal names a field: ``"--"`` makes ``--split-seed`` of ``split_seed``;
    #: anything else is a prefix (``"render."`` makes ``render.spp``).
    FIELD_PREFIX: ClassVar[str] = ""
    #: Labels other than the prefix makes (``{"kind": "--cluster"}``).
    FIELD_LABELS: ClassVar[dict[str, str]] = {}

    @classmethod
    def field_label(cls, name: str) -> str:
        if name in cls.FIELD_LABELS:
            return cls.FIELD_LABELS[name]
        if cls.FIELD_PREFIX == "--":
            return "--" + name.replace("_", "-")
        return cls.FIELD_PREFIX + name

    @classmethod
    def field_error(cls, name: str, value: Any, allowed: str, *, what: str | None = None) -> FieldError:
        return FieldError(cls.field_label(name), value, allowed, what=what, name=name, owner=cls)

    def __post_init__(self):
        for f in fields(self):
            if "part" in f.metadata:
                self._made_part(f.name, f.metadata["part"])
                continue
            rule: Rule | None = f.metadata.get("rule")
            if rule is None:
                continue
            value = getattr(self, f.name)
            try:
                normalised = rule.check(value)
            except Reject as exc:
                allowed = (exc.allowed or rule.allowed) + (f" {exc.detail}" if exc.detail else "")
                raise self.field_error(f.name, value, allowed, what=exc.what) from None
            object.__setattr__(self, f.name, normalised)
        self.check_cross()

    def _made_part(self, name: str, cls: type) -> None:
        """A part given as a dict of its fields is made (and so checked) here; an instance
        was checked when it was made."""
        value = getattr(self, name)
        if isinstance(value, dict) and not set(value) - {f.name for f in fields(cls)}:
            object.__setattr__(self, name, cls(**value))
        elif not isinstance(value, cls):
            raise self.field_error(name, value, f"a {cls.__name__} or a dict of its fields")

    def check_cross(self) -> None:
        """Rules between fields; raise :meth:`field_error` naming one of them."""

    def to_dict(self) -> dict[str, Any]:
        """Every field a file holds, as plain TOML/JSON data."""
        return {
            f.name: f.metadata["rule"].plain(getattr(self, f.name))
            for f in fields(self)
            if "rule" in f.metadata and f.metadata["in_file"]
        }
