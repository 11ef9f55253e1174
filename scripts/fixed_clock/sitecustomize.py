"""Loaded only by scripts/same_outputs.sh (PYTHONPATH): the renderer's clock reads 0, so the
records' render times are 0.0 and two builds of one spec compare byte for byte."""

import sys
import time

_real = time.perf_counter


def perf_counter():
    if sys._getframe(1).f_code.co_filename.endswith("pipeline/render/renderer.py"):
        return 0.0
    return _real()


time.perf_counter = perf_counter
