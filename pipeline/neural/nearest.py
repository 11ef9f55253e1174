"""The nearest-sample baseline of evaluate: the training render of another material of the same
class under the nearest lighting (moved out of pipeline.neural.evaluate, which imports it)."""

from __future__ import annotations

import numpy as np

from pipeline.neural import report


def _material_kind(records, sample_id: str):
    """The sample's material class (report.material_class: uniform dielectric, uniform metal, svbrdf)."""
    return report.material_class(records[sample_id])


class MaterialKinds(dict):
    """sample id -> material class, each found once (a dataset's records are parsed when asked
    for: the nearest-sample search would parse every training record per evaluated sample)."""

    def __init__(self, records):
        super().__init__()
        self.records = records

    def __missing__(self, sample_id: str):
        kind = self[sample_id] = _material_kind(self.records, sample_id)
        return kind


def nearest_sample(sample, training_samples, kinds):
    """The training sample of another material of the same class (uniform dielectric, uniform metal,
    svbrdf) whose lighting
    vector is nearest (with --split train or all, never the sample's own material): squared chord between the sun directions plus ((turbidity difference) / 9)^2
    (turbidity spans 1 to 10); None when the training split holds no material of that kind.
    ``kinds``: sample id -> material class (:class:`MaterialKinds`)."""
    kind = kinds[sample.id]
    d, t = np.asarray(sample.lighting_vector[:3]), sample.lighting_vector[3]
    best, best_distance = None, np.inf
    for other in training_samples:
        if other.material_id == sample.material_id or kinds[other.id] != kind:
            continue
        distance = float(
            np.sum((np.asarray(other.lighting_vector[:3]) - d) ** 2) + ((other.lighting_vector[3] - t) / 9.0) ** 2
        )
        if distance < best_distance:
            best, best_distance = other, distance
    return best
