"""Crash test: SIGKILL the whole `shaderball build` process tree at chosen and random moments
(inside EXR, record, marker, manifest and snapshot writes too), resume, repeat. After every
kill the directory holds only whole files equal to an uninterrupted build's; after every
completion the dataset is byte-identical to it and `validate` passes. More kills:
``scripts/crash_test.py --kills 100`` (docs/resume.md).
"""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


from conftest import crash_module  # noqa: E402

crash = crash_module()

#: Kill points chosen to cover every kind of write at every phase, in a first trial that
#: starts in an empty directory; random kills follow until there are 20.
PLAN = [
    ("write", "spec:1:rename"),  # only a temp file exists: the next run starts anew
    ("write", "description:1:write"),
    ("write", "exr:1:write"),  # half an EXR in a temp file
    ("dask", 3.0),  # 3 s after a local dask cluster's 2 workers exist
    ("write", "exr:2:fsync"),
    ("write", "record:1:renamed"),  # record durable, marker not yet
    ("write", "exr:3:rename"),  # whole EXR in a temp file, not renamed
    ("timer", 4.0),
    ("write", "marker:1:write"),
    ("write", "record:1:write"),
    ("write", "marker:1:renamed"),
    ("write", "exr:2:renamed"),
    ("write", "record:2:fsync"),
    ("write", "manifest:1:write"),  # every shard done, manifest half written
    ("write", "manifest:1:rename"),
    ("none", None),  # completes the first trial
    ("write", "spec:1:write"),  # a fresh trial: killed inside its first write
    ("dask", 2.0),  # all the work still to do
    ("timer", 6.0),
    ("write", "exr:5:write"),
    ("write", "marker:1:fsync"),
]


@pytest.fixture(scope="session")
def reference(tmp_path_factory):
    return crash.shared_reference(tmp_path_factory)


@pytest.mark.slow
def test_twenty_kills_lose_and_duplicate_nothing(tmp_path, reference):
    ref_dir, ref_seconds = reference
    result = crash.run_campaign(
        20,
        tmp_path,
        ref_dir,
        plan=PLAN,
        seed=1,
        reference_seconds=ref_seconds,
        log=lambda line: print(line, flush=True),
    )
    assert result.kills >= 20
    assert result.trials_completed >= 2
    killed_writes = {k.split("@")[0] for k in result.write_kinds()}
    assert killed_writes >= {"exr", "record", "marker", "manifest", "description", "spec"}
    phases = {k.split("@")[1] for k in result.write_kinds()}
    assert phases == set(crash.PHASES)
    dask_kills = [a for a in result.attempts if a.killed and a.mode == "dask"]
    assert dask_kills and max(a.group_size for a in dask_kills) >= 3  # client + 2 worker processes
    assert any(a.temp_files for a in result.attempts if a.killed)  # kills did land mid-write


def test_write_hook_names_file_kinds():
    assert crash.file_kind("/d/shards/s00001/m000002_l1.render.exr") == "exr"
    assert crash.file_kind("/d/shards/s00001/m000002_l1.json") == "record"
    assert crash.file_kind("/d/shards/s00001/COMPLETE.json") == "marker"
    assert crash.file_kind("/d/manifest.jsonl") == "manifest"
    assert crash.file_kind("/d/spec.toml") == "spec"
