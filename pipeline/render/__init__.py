"""Rendering: the one place that loads Mitsuba and holds the chosen variant.

Owns ``mitsuba_env`` (libLLVM selection, variant resolution: the only ``set_variant``),
``scene`` (shapes, sensor), ``bsdf`` (the Cook-Torrance plugin), ``emitter`` and
``sky_probe`` (the sun and sky in Mitsuba), ``gbuffer`` and ``raster`` (exact
screen-space maps), ``renderer`` (one sample, its effects, its retries), ``limits`` (ranges and choices) and the one-sample commands ``command``
(``shaderball render``) and ``scene_command`` (``shaderball scene``). May import the
domain packages, ``pipeline.errors`` and ``pipeline.store`` (to write single files); never
``pipeline.run``, ``pipeline.check`` or dask.
"""
