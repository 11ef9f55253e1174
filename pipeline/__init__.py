"""shaderball's pipeline: datasets of path-traced material renders, built, checked, measured.

Sub-packages by role (docs/architecture.md): ``dataset`` (spec, plan), ``render`` (Mitsuba),
``store`` (the on-disk layout), ``run`` (build, shards, dask), ``check`` (validate, info,
preview), ``bench`` (measurements), ``figures`` (the docs' figures), ``neural`` (the network).
``errors`` is shared by all. Importing this package is cheap: nothing here imports
Mitsuba or dask at import time.
"""

__version__ = "0.2.0"
