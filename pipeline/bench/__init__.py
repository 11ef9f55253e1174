"""Measurements: what accuracy and the build cost in time, and the evidence behind defaults.

``build_bench`` (``shaderball bench``: a build against bare renders), ``effects`` (what the
effects a build leaves out would cost), ``compare`` (two renders equal within noise),
``memory_probe`` (worker memory over many renders), ``sun_benchmark``, ``sky_floor`` and
``probe_scene`` (the sky's measurements). May import anything in the project; nothing in
the project imports it except the CLI and tests.
"""
