"""shaderball's pipeline: datasets of path-traced material renders, built, checked, measured.

Sub-packages by role (docs/architecture.md, in the layer order of pyproject.toml's contract):
``image`` (pixels), ``errors`` (shared by all), ``store`` (the on-disk layout), ``render``
(Mitsuba), ``dataset`` (spec, plan), ``check`` (validate, info, preview), ``study`` (the
accuracy study), ``run`` (build, shards, dask, repair), ``publish`` (publications),
``neural`` (the network), ``bench`` (measurements), ``figures`` (the docs' figures).
Importing this package is cheap: nothing here imports Mitsuba or dask at import time.

Layer 1 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): imports
nothing of the project.
"""

__version__ = "0.2.0"
