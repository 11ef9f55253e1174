"""A dataset sample's stored render: the reference the page shows beside path tracing.

The page compares the network with a new path tracing of the view; for a dataset sample the
render the dataset stores is the ground truth the network was trained against, so it is shown
too. It is read through the project's dataset reader (:func:`pipeline.neural.data.open_dataset`,
as training reads it): a folder or a publication, the file's checksum and size checked against
the manifest, the sample picked by its id from the manifest (never a path a request names).
The render is linear HDR; the hub tone-maps it at the view's exposure like the other pictures.
It lives in the neural stage, beside the reader it uses (torch's), and the CLI hands it to
`shaderball serve` as it hands the network (pipeline.serve needs no torch).
"""

from __future__ import annotations

import functools

import numpy as np

from pipeline.neural.data import open_dataset


class StoredRenders:
    """The stored renders of the dataset ``root`` (a folder or its publication), by sample id."""

    def __init__(self, root: str):
        self.dataset = open_dataset(root)
        samples = self.dataset.samples
        ids = getattr(samples, "ids", None) or [sample.id for sample in samples]
        self.rows = {sample_id: row for row, sample_id in enumerate(ids)}

    def reference(self, sample_id: str) -> tuple[np.ndarray, dict] | None:
        """(linear HDR render (H, W, 3) float32, what the page says of it), or None for an id
        the manifest does not list (the material's own check refuses it first)."""
        row = self.rows.get(sample_id)
        if row is None:
            return None
        sample = self.dataset.samples[row]
        layers = self.dataset.read_layers(sample.render, ("render",), screen=True, flagged=self.dataset.flagged(sample))
        hdr = np.ascontiguousarray(layers["render"][..., :3], dtype=np.float32)
        record = self.dataset.records.get(sample_id) or {}
        requested = (record.get("lighting") or {}).get("requested") or {}
        doc = {
            "sample": sample_id,
            "resolution": int(hdr.shape[0]),
            "spp": (record.get("render") or {}).get("spp"),
            "light": {key: requested.get(key) for key in ("elevation_deg", "azimuth_deg", "turbidity")},
        }
        return hdr, doc


@functools.lru_cache(maxsize=4)
def stored_renders(root: str) -> StoredRenders:
    """The :class:`StoredRenders` of ``root``, opened once (the server asks for it per view)."""
    return StoredRenders(root)
