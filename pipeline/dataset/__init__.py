"""What a dataset is: the spec (parsed and checked), the plan (pure, deterministic), the materials of a plan.

Owns ``spec`` (the TOML spec as frozen, checked sections), ``plan`` (shards, materials,
lightings, seeds: a pure function of the spec), ``materialize`` (a planned material's maps)
and ``record`` (what a sample's record says that follows from the spec and the plan). May
import the domain packages, ``pipeline.errors``, ``pipeline.image`` (EXR compressions) and
the render *limits and choices* (``pipeline.render.limits``, ``pipeline.render.mitsuba_env``
constants); never Mitsuba, dask or the on-disk layout.

Layer 5 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``materials``, ``sky``, ``geometry``, ``pipeline.errors``, ``pipeline.image``,
``pipeline.fields``, ``pipeline.render.limits``, ``pipeline.render.mitsuba_env``,
``pipeline.render.settings``; nothing else of the project.
"""
