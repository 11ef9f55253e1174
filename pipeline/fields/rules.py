"""The rules of typed fields: what a field accepts (:class:`Int`, :class:`Float`,
:class:`Pair`, :class:`Choice`, :class:`Path`, ...), each normalising a value or refusing it
with :class:`Reject`, and how a refused value is shown (:func:`format_value`). A class
declares its fields with them (:mod:`pipeline.fields`), which turns a Reject into the
refusal naming the field.
"""

from __future__ import annotations

import collections
import json
import math
import numbers
import os
import re
from typing import Any

#: A field with no default (required).
MISSING = object()


class AsTyped(str):
    """A command-line word echoed in a refusal as the user typed it: ``--spp: 0,1 is not
    allowed`` rather than the value it was read as (``[0, 1]``)."""


def format_value(value: Any) -> str:
    """A value as TOML would spell it (a command-line word as it was typed), shortened for a
    one-line message."""
    if isinstance(value, AsTyped):
        text = str(value)
    elif value is MISSING:
        text = "(missing)"
    elif value is None:
        text = "none"
    elif isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, str):
        text = json.dumps(value, ensure_ascii=False)
    elif isinstance(value, float):
        text = (
            "nan"
            if math.isnan(value)
            else ("inf" if value == math.inf else "-inf" if value == -math.inf else repr(value))
        )
    elif isinstance(value, (list, tuple)):
        text = "[" + ", ".join(format_value(v) for v in value) + "]"
    elif isinstance(value, dict):
        text = "{" + ", ".join(f"{k} = {format_value(v)}" for k, v in value.items()) + "}"
    else:
        text = repr(value)
    return text if len(text) <= 120 else text[:117] + "..."


class Reject(Exception):
    """Raised by a rule; the class turns it into a FieldError naming the field. ``detail``
    follows what is allowed; ``what`` replaces "<value> is not allowed"; ``allowed``
    replaces the rule's words for what is allowed."""

    def __init__(self, detail: str = "", *, what: str | None = None, allowed: str | None = None):
        super().__init__(detail)
        self.detail = detail
        self.what = what
        #: What is allowed, where it is not the rule's own words (one item of :class:`Many`).
        self.allowed = allowed


# --------------------------------------------------------------------------- rules


def is_number(v: Any) -> bool:
    # bool is an int subclass in Python: `spp = true` must not pass as 1.
    return isinstance(v, numbers.Real) and not isinstance(v, bool)


def is_finite(v: Any) -> bool:
    """A number that is finite as a float (an integer too large for one is not: 10**400)."""
    if not is_number(v):
        return False
    try:
        return math.isfinite(float(v))
    except OverflowError:
        return False


def is_integer(v: Any) -> bool:
    # numbers.Integral admits numpy integers (from Python callers) but not floats like 8.0.
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


#: A number as a command line writes it: ASCII digits only. Python's int() and float() also read
#: other scripts' digits ("１" full-width, "٣" Arabic-Indic) and underscores ("1_000").
_ASCII_INT = re.compile(r"[+-]?[0-9]+")
_ASCII_FLOAT = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?|[+-]?(inf|infinity|nan)", re.I)


def parse_int(text: str) -> int:
    """``text`` (ASCII digits, a sign, spaces around) as an int; ValueError for anything else."""
    word = text.strip(" \t")
    if not _ASCII_INT.fullmatch(word):
        raise ValueError(text)
    return int(word)


def parse_float(text: str) -> float:
    """``text`` (ASCII digits, a point, an exponent, spaces around) as a float; ValueError else."""
    word = text.strip(" \t")
    if not _ASCII_FLOAT.fullmatch(word):
        raise ValueError(text)
    return float(word)


class Rule:
    """What a field accepts: :meth:`check` returns the normalised value or raises Reject."""

    allowed: str
    #: What the reference page says is allowed, when ``allowed`` is computed at run time.
    doc_allowed: str | None = None
    #: The Python type a command-line value is parsed as (str, int, float, bool).
    py_type: type = str

    def check(self, value: Any) -> Any:
        raise NotImplementedError

    def parse(self, text: str) -> Any:
        """A command-line word as the value :meth:`check` takes (ValueError: not one)."""
        return {int: parse_int, float: parse_float}.get(self.py_type, self.py_type)(text)

    @staticmethod
    def plain(value: Any) -> Any:
        """The value as plain TOML/JSON data (tuples become lists)."""
        return list(value) if isinstance(value, tuple) else value

    @property
    def brief(self) -> str:
        """The allowed values as a short phrase for ``--help``."""
        return self.doc_allowed or self.allowed


class Int(Rule):
    py_type = int

    def __init__(self, lo: int, hi: int, also: tuple[int, ...] = (), also_text: str = ""):
        self.lo, self.hi, self.also = lo, hi, also
        self.allowed = f"an integer from {lo} to {hi}" + (f", or {also_text}" if also else "")

    def check(self, value):
        if not is_integer(value):
            raise Reject()
        value = int(value)
        if value in self.also or self.lo <= value <= self.hi:
            return value
        raise Reject()

    @property
    def brief(self) -> str:
        hi = self.hi
        # a top of 2^k - 1 (a seed's) reads as such
        top = f"2^{hi.bit_length()}-1" if hi >= 2**31 - 1 and hi & (hi + 1) == 0 else str(hi)
        return f"{self.lo} to {top}" + ("".join(f", or {a}" for a in self.also))


class Float(Rule):
    """A finite number in [lo, hi]; ``lo_open``/``hi_open`` leave an end out."""

    py_type = float

    def __init__(self, lo: float, hi: float, *, lo_open: bool = False, hi_open: bool = False):
        self.lo, self.hi, self.lo_open, self.hi_open = lo, hi, lo_open, hi_open
        if lo_open or hi_open:
            self.allowed = f"a finite number in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
        else:
            self.allowed = f"a finite number from {lo:g} to {hi:g}"

    def check(self, value):
        if not is_finite(value):
            raise Reject()
        above = value > self.lo if self.lo_open else value >= self.lo
        below = value < self.hi if self.hi_open else value <= self.hi
        if not (above and below):
            raise Reject()
        return float(value)

    @property
    def brief(self) -> str:
        return f"{'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}{')' if self.hi_open else ']'}"


class Pair(Rule):
    """A closed interval [lo, hi]; lo == hi fixes the value."""

    def __init__(self, lo: float, hi: float, max_span: float | None = None):
        self.lo, self.hi, self.max_span = lo, hi, max_span
        self.allowed = f"a pair [lo, hi] of finite numbers with {lo:g} <= lo <= hi <= {hi:g}"
        if max_span is not None:
            self.allowed += f" and hi - lo <= {max_span:g}"

    def check(self, value):
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            raise Reject()
        if not all(is_finite(v) for v in value):
            raise Reject()
        lo, hi = float(value[0]), float(value[1])
        if lo > hi:
            raise Reject(f"(lo {lo:g} > hi {hi:g}: the range is inverted)")
        if lo < self.lo or hi > self.hi:
            raise Reject()
        if self.max_span is not None and hi - lo > self.max_span:
            raise Reject(f"(span {hi - lo:g})")
        return (lo, hi)


class Triple(Rule):
    """Three finite numbers, each in [lo, hi] (None: unbounded); ``R,G,B`` on a command line."""

    def __init__(self, lo: float | None = 0.0, hi: float | None = 1.0, allowed: str | None = None):
        self.lo, self.hi = lo, hi
        self.allowed = allowed or "three comma-separated numbers" + (f" in [{lo:g}, {hi:g}]" if lo is not None else "")

    def parse(self, text: str):
        return tuple(parse_float(x) for x in text.split(","))

    def check(self, value):
        if not isinstance(value, (list, tuple)) or len(value) != 3:
            raise Reject()
        if not all(is_finite(v) for v in value):
            raise Reject()
        if self.lo is not None and not all(self.lo <= v <= self.hi for v in value):
            raise Reject()
        return tuple(float(v) for v in value)

    @property
    def brief(self) -> str:
        return self.allowed


class Choice(Rule):
    """One string from ``options`` (a tuple, or a callable asked at check time)."""

    def __init__(self, options, doc_allowed: str | None = None):
        self._options = options
        self.doc_allowed = doc_allowed

    @property
    def options(self) -> tuple[str, ...]:
        return tuple(self._options() if callable(self._options) else self._options)

    @property
    def allowed(self) -> str:
        return "one of " + ", ".join(json.dumps(o) for o in self.options)

    def check(self, value):
        if not isinstance(value, str) or value not in self.options:
            raise Reject()
        return value

    @property
    def brief(self) -> str:
        return ", ".join(self.options)


class Text(Rule):
    def __init__(self, pattern: str, text: str):
        self.pattern = re.compile(pattern)
        self.allowed = text

    def check(self, value):
        if not isinstance(value, str) or not self.pattern.fullmatch(value):
            raise Reject()
        return value


class Path(Rule):
    """A non-empty path (file or folder). ``exists``: ``"file"``, ``"folder"`` or ``"any"``
    refuses a path that is not there (an input the command reads); None leaves it to the
    consumer (an output it creates)."""

    def __init__(self, what: str = "a path", *, empty_ok: bool = False, exists: str | None = None):
        self.allowed = what
        self.empty_ok = empty_ok
        self.exists = exists

    def check(self, value):
        if not isinstance(value, str) or not (value or self.empty_ok):
            raise Reject()
        if self.exists is not None and value:
            if not os.path.lexists(value):
                raise Reject(what=f"{format_value(value)} does not exist")
            if self.exists == "file" and os.path.isdir(value):
                raise Reject(what=f"{format_value(value)} is a folder")
            if self.exists == "folder" and not os.path.isdir(value):
                raise Reject(what=f"{format_value(value)} is not a folder")
        return value


class IntList(Rule):
    """Integers, each from ``lo`` to ``hi``; ``"1,2,4"`` on a command line. ``none``: a word
    (any case) that stands for no value at all (an empty tuple); ``distinct``: no repeats."""

    metavar = "N,N,..."

    def __init__(self, lo: int, hi: int, *, none: str | None = None, distinct: bool = False, min_len: int = 1):
        self.lo, self.hi, self.none, self.distinct, self.min_len = lo, hi, none, distinct, min_len
        self.allowed = f"comma-separated integers from {lo} to {hi}" + (f", or {none}" if none else "")
        if min_len > 1:
            self.allowed = f"{min_len} or more " + self.allowed

    def parse(self, text: str):
        if self.none is not None and text.strip().lower() == self.none:
            return ()
        try:
            return tuple(parse_int(x) for x in text.split(","))
        except ValueError:
            raise ValueError(text) from None

    @property
    def brief(self) -> str:
        return f"{self.lo} to {self.hi} each" + (f", or {self.none}" if self.none else "")

    def check(self, value):
        if not isinstance(value, (list, tuple)) or not all(is_integer(v) for v in value):
            raise Reject()
        if not value and self.none is not None:
            return ()
        if len(value) < self.min_len or not all(self.lo <= v <= self.hi for v in value):
            raise Reject()
        if self.distinct and len(set(value)) != len(value):
            raise Reject("(repeated values)")
        return tuple(int(v) for v in value)


class Many(Rule):
    """One or more values, each checked by ``item`` (a command's repeated operand, such as
    ``REPORT.json...``); stored as a tuple."""

    def __init__(self, item: Rule):
        self.item = item
        self.py_type = item.py_type
        self.allowed = f"one or more of: {item.allowed}"

    @property
    def brief(self) -> str:
        return self.item.brief

    def check(self, value):
        if isinstance(value, str) or not isinstance(value, (list, tuple)) or not value:
            raise Reject()
        return tuple(self._item(v) for v in value)

    def _item(self, value):
        """One value checked; refused as the command line refuses that word."""
        try:
            return self.item.check(value)
        except Reject as exc:
            what = exc.what or f"{format_value(value)} is not allowed"
            raise Reject(exc.detail, what=what, allowed=exc.allowed or self.item.allowed) from None


class Bool(Rule):
    allowed = "true or false"
    py_type = bool

    def check(self, value):
        if not isinstance(value, bool):
            raise Reject()
        return value


class Optional(Rule):
    """``rule``'s values or None (the field's default then applies elsewhere)."""

    def __init__(self, rule: Rule, none_text: str = "unset", *, default_text: str | None = None):
        self.rule = rule
        self.none_text = none_text
        #: What None means, as --help says it ("the spec's").
        self.default_text = default_text
        self.py_type = rule.py_type

    @property
    def allowed(self) -> str:
        return f"{self.rule.allowed}, or {self.none_text}"

    @property
    def brief(self) -> str:
        return self.rule.brief

    def check(self, value):
        return None if value is None else self.rule.check(value)

    def parse(self, text: str):
        return self.rule.parse(text)


class StrList(Rule):
    """A list of distinct strings, optionally from a set; stored as a tuple.

    ``options`` may be a callable, asked at check time, so the allowed set can come from
    a package imported lazily.
    """

    def __init__(self, options, what: str, doc_allowed: str | None = None):
        self._options = options
        self._what = what
        self.doc_allowed = doc_allowed

    @property
    def options(self) -> tuple[str, ...] | None:
        return self._options() if callable(self._options) else self._options

    def parse(self, text: str):
        return tuple(word.strip() for word in text.split(",") if word.strip())

    @property
    def allowed(self) -> str:
        options = self.options
        if options is None:
            return f"a list of distinct {self._what}"
        return f"a list of distinct {self._what} from " + ", ".join(json.dumps(o) for o in options)

    def check(self, value):
        if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
            raise Reject()
        if len(set(value)) != len(value):  # counted in one pass: 20,000 entries took 10 s with list.count
            dupes = sorted(v for v, n in collections.Counter(value).items() if n > 1)
            raise Reject("(repeated: " + ", ".join(json.dumps(d) for d in dupes) + ")")
        options = self.options
        if options is not None:
            bad = [v for v in value if v not in options]
            if bad:
                raise Reject("(unknown: " + ", ".join(json.dumps(b) for b in bad) + ")")
        return tuple(value)
