"""Option values the command parses before a library function sees them; refused in the
project's one wording (:func:`pipeline.errors.bad_value`)."""

from __future__ import annotations

from pipeline.errors import bad_value


def parse_int_list(field: str, text: str, bounds: tuple[int, int], none: str | None = None) -> tuple[int, ...]:
    """``"1,2,4"`` -> (1, 2, 4); ``none`` (any case), if given, -> (). Only the syntax is
    checked here: the library checks each value against ``bounds``, which name what the
    refusal allows."""
    if none is not None and text.strip().lower() == none:
        return ()
    try:
        return tuple(int(x) for x in text.split(","))
    except ValueError:
        allowed = f"comma-separated integers from {bounds[0]} to {bounds[1]}" + (f", or {none}" if none else "")
        raise bad_value(field, text, allowed) from None
