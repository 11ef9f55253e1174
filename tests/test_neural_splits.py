"""Splits are by material, disjoint, complete and deterministic."""

import pytest

from pipeline.errors import ShaderballError
from pipeline.neural.splits import split_materials

IDS = [f"m{i:06d}" for i in range(50)]


def test_disjoint_complete_and_sized():
    train, test = split_materials(IDS, 0.2, seed=3)
    assert set(train).isdisjoint(test)
    assert sorted(train + test) == IDS
    assert len(test) == 10


def test_deterministic_in_the_id_set_and_seed():
    assert split_materials(IDS, 0.2, 3) == split_materials(list(reversed(IDS)) + IDS[:5], 0.2, 3)
    assert split_materials(IDS, 0.2, 3) != split_materials(IDS, 0.2, 4)


def test_edges():
    assert split_materials(IDS, 0.0, 1) == (IDS, [])
    train, test = split_materials(IDS[:2], 0.9, 1)
    assert len(train) == 1 and len(test) == 1
    with pytest.raises(ShaderballError, match="^test_fraction: .*one material.*2 or more"):
        split_materials(IDS[:1], 0.2, 1)
    with pytest.raises(ShaderballError, match="^test_fraction: "):
        split_materials(IDS, 1.0, 1)
