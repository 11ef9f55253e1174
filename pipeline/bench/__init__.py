"""Measurements: what accuracy and the build cost in time, and the evidence behind defaults.

``command`` (``shaderball bench``'s request, :class:`~pipeline.bench.command.BenchRequest`: the
build, effects or scale benchmark), ``build_bench`` (a build against bare renders), ``scale``
(every command against the dataset's size), ``estimate``
(``shaderball plan``: a spec's counts, disk and time from its first renders), ``effects`` (what the
effects a build leaves out would cost), ``compare`` (two renders equal within noise),
``memory_probe`` (worker memory over many renders), ``sun_benchmark``, ``sky_floor`` and
``probe_scene`` (the sky's measurements). Nothing in the project imports it except the CLI
and tests.

Layer 8 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``pipeline``, ``materials``, ``sky``, ``geometry``, ``pipeline.image``, ``pipeline.errors``,
``pipeline.fields``, ``pipeline.store``, ``pipeline.render``, ``pipeline.dataset``,
``pipeline.check``, ``pipeline.study``, ``pipeline.run``, ``pipeline.publish``; nothing else
of the project.
"""
