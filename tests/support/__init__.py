"""Helpers shared by the tests (importable as ``support``: pytest puts tests/ on sys.path)."""

from pipeline.render.mitsuba_env import LLVM_VARIANT

#: The Mitsuba variant the CPU tests render with (the edge where tests choose it).
VARIANT = LLVM_VARIANT
