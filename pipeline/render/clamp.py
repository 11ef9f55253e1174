"""A luminance clamp on each camera path's contribution: Mitsuba's ``path`` has none.

``shaderball_clamp`` is a sampling integrator that wraps another (the path tracer) and
scales every camera sample's radiance L down to luminance ``limit`` when Y(L) exceeds it,
keeping its colour: ``L * min(1, limit / Y(L))``. It runs inside the ``moment``
integrator, so the recorded variance is that of the clamped estimator.

A clamp is **biased**: it removes energy (the rare bright paths that make fireflies carry
real light: sun caustics through the ball, glints), so the clamped image converges to a
darker image than the reference. docs/accuracy.md measures that bias against references.
Like the BSDF plugin, the class is defined once per Mitsuba variant, after it is loaded.
"""

from __future__ import annotations

from pipeline.render.mitsuba_env import register_plugin

PLUGIN_NAME = "shaderball_clamp"


def wrap_in_clamp(nested: dict, limit: float) -> dict:
    """The integrator dict of ``nested`` with its camera samples clamped to luminance ``limit``."""
    return {"type": PLUGIN_NAME, "limit": float(limit), "nested": nested}


def register_clamp(variant: str) -> None:
    """Register ``shaderball_clamp`` with Mitsuba for ``variant``; calling it again is a no-op."""
    register_plugin(variant, PLUGIN_NAME, "integrator", _define_class)


def _define_class(mi):
    import drjit as dr

    class ClampIntegrator(mi.SamplingIntegrator):
        def __init__(self, props):
            super().__init__(props)
            self.nested = props.get("nested")
            self.limit = float(props.get("limit"))

        def sample(self, scene, sampler, ray, medium=None, active=True):
            radiance, valid, aovs = self.nested.sample(scene, sampler, ray, medium, active)
            y = mi.luminance(radiance)
            scale = dr.select(y > self.limit, self.limit / dr.maximum(y, 1e-30), 1.0)
            return radiance * scale, valid, aovs

        def aov_names(self):
            return self.nested.aov_names()

        def to_string(self):
            return f"ClampIntegrator[limit={self.limit}, nested={self.nested}]"

    return ClampIntegrator
