"""Train/test splits by material: a material's lightings never straddle the split."""

from __future__ import annotations

import numpy as np

from pipeline.neural.config import TrainConfig

#: Key of the split's random stream beside the run's seed (any fixed number would do).
SPLIT_STREAM = 0x5B11


def split_materials(material_ids, test_fraction: float, seed: int) -> tuple[list[str], list[str]]:
    """Deterministic split of material ids into (train, test), each sorted.

    The ids are sorted first, so the split depends only on the set of ids, the fraction
    and the seed. ``round(test_fraction * n)`` materials (at least 1, at most n - 1) go
    to test when ``test_fraction > 0``.
    """
    if not 0.0 <= test_fraction < 1.0:
        raise TrainConfig.field_error("test_fraction", test_fraction, "a fraction in [0, 1)")
    ids = sorted(set(material_ids))
    if test_fraction == 0.0:
        return ids, []
    if len(ids) < 2:
        raise TrainConfig.field_error(
            "test_fraction",
            test_fraction,
            "0, with a dataset of one material (holding some out for testing takes 2 or more)",
            what=f"{test_fraction:g} is not allowed: the dataset has {len(ids)} material(s)",
        )
    n_test = min(max(1, round(test_fraction * len(ids))), len(ids) - 1)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), SPLIT_STREAM]))
    order = rng.permutation(len(ids))
    test = sorted(ids[i] for i in order[:n_test])
    train = sorted(ids[i] for i in order[n_test:])
    return train, test
