"""Rendering: the one place that loads Mitsuba and holds the chosen variant.

Owns ``mitsuba_env`` (libLLVM selection, variant resolution: the only ``set_variant``),
``scene`` (shapes, sensor), ``bsdf`` (the Cook-Torrance plugin), ``emitter`` and
``sky_probe`` (the sun and sky in Mitsuba), ``gbuffer`` and ``raster`` (exact
screen-space maps), ``renderer`` (one sample, its effects, its retries), ``limits``
(ranges and choices) and the one-sample commands ``command`` (``shaderball render``) and
``scene_command`` (``shaderball scene``). It writes single files through
``pipeline.store``; never dask. Pixels (tone maps, statistics) are ``pipeline.image``'s.

Layer 4 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``materials``, ``sky``, ``geometry``, ``pipeline.errors``, ``pipeline.image``,
``pipeline.store``, ``pipeline.fields``; nothing else of the project.
"""
