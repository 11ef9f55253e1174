"""Publishing a dataset, and reading a published one without trusting it.

Owns the published layout (``names``: tar shards, samples table, card, Croissant metadata,
checksums), writing it (``writer``: `shaderball publish`), and reading it back
(``reader``: `shaderball verify`, `shaderball unpack` and :func:`iter_samples` for the
training stage), with the archive checks that make reading a received copy safe
(``tarsafe``, ``exrcheck``). May import ``pipeline.store``, ``pipeline.check``,
``pipeline.dataset`` and ``pipeline.errors``; never Mitsuba, dask or torch.
"""

from pipeline.publish.reader import iter_folder_samples, iter_samples, open_publication
from pipeline.publish.refusal import DEFAULT_LIMITS, Limits, Refused

__all__ = ["DEFAULT_LIMITS", "Limits", "Refused", "iter_folder_samples", "iter_samples", "open_publication"]
