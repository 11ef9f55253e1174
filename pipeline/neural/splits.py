"""Train/test splits by material: a material's lightings never straddle the split; and a
run's split as config.json records it (:class:`RunSplit`): by material, with whole objects held
out (``--held-out-objects``: every material on them, under every light) and lightings whose
environment-map rotation lies in a range held out (``--held-out-rotations``: those samples of
the training materials go to the test split, the rest of the material trains)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.neural.config import TrainConfig
from pipeline.neural.scene_inputs import material_objects, scenes

#: Key of the split's random stream beside the run's seed (any fixed number would do).
SPLIT_STREAM = 0x5B11
#: Key of the stream that orders the training materials for --train-materials (nested subsets).
SUBSET_STREAM = 0x5B5E


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


def select_training_materials(train_ids: list[str], count: int | None, seed: int) -> list[str]:
    """The first ``count`` training materials in an order drawn from ``seed`` (sorted):
    nested subsets, so a run on 64 materials sees a subset of one on 128."""
    if count is None:
        return train_ids
    if count > len(train_ids):
        raise TrainConfig.field_error(
            "train_materials", count, f"at most {len(train_ids)}, the training split's materials"
        )
    order = np.random.default_rng(np.random.SeedSequence([int(seed), SUBSET_STREAM])).permutation(len(train_ids))
    return sorted(train_ids[i] for i in order[:count])


@dataclass(frozen=True)
class RunSplit:
    """A run's split: training and test materials, the objects and the rotation range held out."""

    train: list
    test: list
    held_out_objects: tuple = ()
    held_out_rotations: tuple | None = None

    def record(self) -> dict:
        """config.json's ``split`` (the keys of the held-out objects and rotations only when set)."""
        record = {"train": self.train, "test": self.test}
        if self.held_out_objects:
            record["held_out_objects"] = list(self.held_out_objects)
        if self.held_out_rotations is not None:
            record["held_out_rotations"] = list(self.held_out_rotations)
        return record


def run_split(config: TrainConfig, source) -> RunSplit:
    """The split of a new run of ``config`` on ``source``: held-out objects' materials all to
    test, the others split by ``test_fraction``, the training ones cut to ``train_materials``;
    a named object the dataset lacks, or no object left to train on, is refused."""
    seed, held = config.splitting_seed, tuple(config.held_out_objects or ())
    ids, objects = source.material_ids, {}
    if held:
        objects = material_objects(source)
        present = sorted(set(objects.values()))
        unknown = [name for name in held if name not in present]
        if unknown:
            raise TrainConfig.field_error(
                "held_out_objects",
                ",".join(held),
                f"objects of the dataset: {', '.join(present)}",
                what=f"{', '.join(unknown)}: not an object of the dataset",
            )
        if set(present) <= set(held):
            raise TrainConfig.field_error(
                "held_out_objects",
                ",".join(held),
                f"at most {len(present) - 1} of the dataset's objects ({', '.join(present)}): one must be left "
                "to train on",
                what="every object of the dataset is held out",
            )
        ids = [m for m in ids if objects[m] not in held]
    pool, test = split_materials(ids, config.test_fraction, seed)
    train = select_training_materials(pool, config.train_materials, seed)
    test = sorted(test + [m for m, name in objects.items() if name in held])
    rotations = config.held_out_rotations
    if rotations is not None:
        _check_rotations(source, train, rotations)
    return RunSplit(train, test, held, rotations)


def _check_rotations(source, train: list, rotations: tuple) -> None:
    """Refuse a rotation range on a dataset with no environment-lit sample, or one that leaves no
    training sample."""
    lo, hi = rotations
    by_id, keep = scenes(source), set(train)
    lit = [by_id[s.id].rotation_deg for s in source.samples if s.material_id in keep]
    lit = [r for r in lit if r is not None]
    text = f"{lo:g},{hi:g}"
    if not lit:
        raise TrainConfig.field_error(
            "held_out_rotations",
            text,
            "unset on a dataset without environment-lit training samples",
            what=f"{text}: no training sample is lit by an environment map",
        )
    if len(lit) == len([s for s in source.samples if s.material_id in keep]) and all(lo <= r <= hi for r in lit):
        raise TrainConfig.field_error(
            "held_out_rotations",
            text,
            "a range that leaves training samples",
            what=f"{text} holds out every training sample",
        )


def split_samples(source, split: dict, which: str):
    """The samples of a run's ``split`` record (config.json's) ``which`` ("train" or "test") of
    ``source``: its materials, and with ``held_out_rotations`` the samples of the training
    materials whose map rotation lies in the range moved from train to test."""
    rotations = split.get("held_out_rotations")
    if rotations is None:
        return source.subset(split.get(which) or [])
    lo, hi = float(rotations[0]), float(rotations[1])
    by_id = scenes(source)
    train, test = set(split.get("train") or []), set(split.get("test") or [])

    def held(sample) -> bool:
        rotation = by_id[sample.id].rotation_deg
        return rotation is not None and lo <= rotation <= hi

    if which == "train":
        return sample_view(source.subset(train), lambda s: not held(s))
    return sample_view(source.subset(train | test), lambda s: s.material_id in test or held(s))


def sample_view(dataset, keep):
    """``dataset`` (a material subset) cut to the samples ``keep(sample)`` accepts, in order."""
    samples = dataset.samples
    if hasattr(samples, "rows"):  # SampleColumns: a view of the same columns, fewer rows
        view = type(samples).__new__(type(samples))
        view.__dict__.update(samples.__dict__)
        view.rows = np.asarray([row for row in samples.rows if keep(samples._one(int(row)))], np.int64)
    else:
        view = [s for s in samples if keep(s)]
    dataset.samples = view
    dataset.material_ids = sorted({s.material_id for s in view})
    return dataset
