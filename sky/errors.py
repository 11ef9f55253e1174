"""The sky package's error type and its one wording of a refused value.

Domain packages import nothing of ``pipeline``; :data:`pipeline.errors.USER_ERRORS`
lists this type so the CLI reports it like its own errors (a clear message, exit 2).
A refusal reads as the project's every refusal: ``<field>: <value> is not allowed;
<what is allowed>`` (``pipeline.fields.FieldError`` words the commands' and the spec's).

materials/errors.py is its twin on purpose: the domain packages import neither each other nor
``pipeline`` (docs/architecture.md), and a module both could share would be a new top-level
package, outside the layout the design fixes, for some 40 lines.
"""

from __future__ import annotations

import json
import math
import numbers


class SkyError(ValueError):
    """A refused sky input: the message names the field, the value and what is allowed."""

    #: The exit code the CLI gives it (the same as pipeline.errors.ShaderballError).
    exit_code = 2


def shown(value) -> str:
    """A value as a refusal quotes it (as ``pipeline.fields.format_value`` does)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, numbers.Integral):
        return repr(int(value))
    if isinstance(value, numbers.Real):  # numpy floats too: 3.0, never np.float64(3.0)
        value = float(value)
        if not math.isfinite(value):
            return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(shown(v) for v in value) + "]"
    return repr(value)


def refusal(field: str, value, allowed: str) -> SkyError:
    """``<field>: <value> is not allowed; <allowed>``."""
    return SkyError(f"{field}: {shown(value)} is not allowed; {allowed}")


def number_allowed(lo: float, hi: float) -> str:
    """What a number in [lo, hi] allows, in the words of ``pipeline.fields.rules.Float``."""
    return f"a finite number from {lo:g} to {hi:g}"


def pair_allowed(lo: float, hi: float, max_span: float | None = None) -> str:
    """What a closed interval within [lo, hi] allows, in the words of ``pipeline.fields.rules.Pair``."""
    text = f"a pair [lo, hi] of finite numbers with {lo:g} <= lo <= hi <= {hi:g}"
    return text + (f" and hi - lo <= {max_span:g}" if max_span is not None else "")
