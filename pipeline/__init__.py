"""shaderball pipeline: specs, planning, Mitsuba scenes and renders, storage, orchestration.

Importing this package is cheap: nothing here imports Mitsuba or dask at import time.
"""

__version__ = "0.1.0"
