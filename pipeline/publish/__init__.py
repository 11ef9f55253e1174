"""Publishing a dataset, and reading a published one without trusting it.

Owns the published layout (``names``: tar shards, samples table, card, Croissant metadata,
checksums), writing it (``writer``: `shaderball publish`), and reading it back
(``reader``: `shaderball verify`, `shaderball unpack` and :func:`iter_samples` for the
training stage), with the archive checks that make reading a received copy safe
(``tarsafe``, ``exrcheck``). Never Mitsuba, dask or torch, nor the build (``pipeline.run``).

Layer 7 of 10 in the layer contract (pyproject.toml, [tool.shaderball.layers]): may import
``pipeline.errors``, ``pipeline.fields``, ``pipeline.image``, ``pipeline.store``,
``pipeline.dataset``, ``pipeline.check``; nothing else of the project.
"""

from pipeline.publish.reader import iter_folder_samples, iter_samples, open_publication
from pipeline.publish.refusal import DEFAULT_LIMITS, Limits, Refused

__all__ = ["DEFAULT_LIMITS", "Limits", "Refused", "iter_folder_samples", "iter_samples", "open_publication"]
