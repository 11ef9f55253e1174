"""Counting what drjit compiles: the build benchmark's and the accuracy study's one counter."""

from __future__ import annotations


class KernelCounter:
    """Counts drjit kernels compiled (not found in the memory or disk cache) while active, and
    their backend compile time; the counts add up over every ``with`` block it is used in.

    A kernel's hash covers the Mitsuba objects alive in the process (virtual calls are
    traced over every registered instance), so two scenes alive at once give new kernels:
    a measurement that wants none keeps one scene alive at a time, as a build worker does.
    """

    def __init__(self):
        import drjit as dr

        self._dr = dr
        self.compiled = 0
        self.compile_s = 0.0

    def __enter__(self):
        self._dr.set_flag(self._dr.JitFlag.KernelHistory, True)
        self._dr.kernel_history()  # clears
        return self

    def __exit__(self, *exc):
        dr = self._dr
        for k in dr.kernel_history():
            if k["type"] == dr.KernelType.JIT and not k.get("cache_hit"):
                self.compiled += 1
                self.compile_s += k.get("backend_time", 0.0) / 1000.0
        dr.set_flag(dr.JitFlag.KernelHistory, False)
