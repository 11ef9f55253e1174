"""Helpers shared by the tests (importable as ``support``: pytest puts tests/ on sys.path)."""

import os

from pipeline.render.mitsuba_env import LLVM_VARIANT

#: The repository, and the two shipped specs the tests read, as the str paths a command line takes.
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SMOKE = os.path.join(REPO, "manifests", "smoke.toml")
PAPER = os.path.join(REPO, "manifests", "paper.toml")

#: The Mitsuba variant the CPU tests render with (the edge where tests choose it).
VARIANT = LLVM_VARIANT
