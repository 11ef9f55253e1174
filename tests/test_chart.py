"""Log-axis ticks (pipeline.image.chart): 1-2-5 over wide spans, every whole multiple over narrow
ones, so every line on a chart has a labelled value near it."""

import math

import pytest

from pipeline.image.chart import _log_ticks


def _ticks(lo: float, hi: float) -> list[float]:
    return [round(10**t, 6) for t in _log_ticks(math.log10(lo), math.log10(hi))]


def test_a_span_of_decades_ticks_at_1_2_5():
    assert _ticks(1000, 50000) == [1000, 2000, 5000, 10000, 20000, 50000]


def test_many_decades_tick_at_the_powers_only():
    assert _ticks(0.5, 1300) == [1, 10, 100, 1000]


@pytest.mark.parametrize(("lo", "hi"), [(70, 441), (250, 900), (1.1, 4.5)])
def test_a_narrow_span_gets_three_ticks_or_more_and_one_near_its_top(lo, hi):
    ticks = _ticks(lo, hi)
    assert len(ticks) >= 3 and all(lo <= t <= hi for t in ticks), ticks
    assert math.log10(hi) - math.log10(max(ticks)) < 0.15, ticks  # a value beside the top line
