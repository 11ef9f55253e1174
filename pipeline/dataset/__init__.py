"""What a dataset is: the spec (parsed and checked), the plan (pure, deterministic), the materials of a plan.

Owns ``spec`` (the TOML spec as frozen, checked sections), ``plan`` (shards, materials,
lightings, seeds: a pure function of the spec) and ``materialize`` (a planned material's
maps). May import the domain packages, ``pipeline.errors`` and the render *limits and
choices* (``pipeline.render.limits``, ``pipeline.render.mitsuba_env`` constants); never
Mitsuba, dask or the on-disk layout.
"""
