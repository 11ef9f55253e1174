"""A dataset's determinism guarantee (dataset.json ``determinism``, docs/manifest.md) and how
resume and ``validate --repair`` treat a dataset whose re-renders are not byte-identical.

Renders here are llvm's, which are byte-identical. A within-noise dataset (cuda's) is made by
faking the guarantee field, and a re-render that differs from its lost copy by giving the
lost copy's records another digest (the lost bytes are gone: their recorded SHA-256 is all
a repair can know of them). The renderer is never mocked.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pytest

from pipeline.check.validate import validate
from pipeline.errors import SetupError
from pipeline.render.mitsuba_env import BYTE_IDENTICAL, GUARANTEE_BASIS, WITHIN_NOISE, weakest_guarantee
from pipeline.run.build import build
from pipeline.run.cluster.options import ClusterOptions
from pipeline.run.repair import repair
from support import VARIANT

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"
SHARD = "shards/s00001"
LOST = "m000002_l1"
FAKE_DIGEST = "0" * 64


def _copy(reference: Path, tmp_path: Path, guarantee: str | None = None) -> Path:
    out = tmp_path / "ds"
    shutil.copytree(reference, out)
    if guarantee is not None:
        path = out / "dataset.json"
        description = json.loads(path.read_text())
        description["determinism"] = {"guarantee": guarantee, "basis": GUARANTEE_BASIS[guarantee]}
        path.write_text(json.dumps(description))
    return out


def _files(root: Path) -> dict[str, tuple[int, int]]:
    """(inode, mtime) of every file: a rewrite, even of the same bytes, changes one of them."""
    return {
        p.relative_to(root).as_posix(): (p.stat().st_ino, p.stat().st_mtime_ns) for p in root.rglob("*") if p.is_file()
    }


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _render_digests(record: dict) -> list[str]:
    return [e["sha256"] for e in record["files"] if e["role"] == "render"]


def _every_copy(root: Path, sample_id: str) -> list[dict]:
    """The sample's record file, its marker entry and its manifest line."""
    shard = root / SHARD
    marker = json.loads((shard / "COMPLETE.json").read_text())
    manifest = [json.loads(line) for line in (root / "manifest.jsonl").read_text().splitlines()]
    return [
        json.loads((shard / f"{sample_id}.json").read_text()),
        next(r for r in marker["records"] if r["id"] == sample_id),
        next(r for r in manifest if r["id"] == sample_id),
    ]


def _give_lost_copy_another_digest(root: Path, sample_id: str) -> None:
    """Every copy of the record says the (lost) render held other bytes than a re-render gives."""

    def fake(record):
        for entry in record["files"]:
            if entry["role"] == "render":
                entry["sha256"] = FAKE_DIGEST
        return record

    shard = root / SHARD
    path = shard / f"{sample_id}.json"
    path.write_text(json.dumps(fake(json.loads(path.read_text()))))
    marker = json.loads((shard / "COMPLETE.json").read_text())
    marker["records"] = [fake(r) if r["id"] == sample_id else r for r in marker["records"]]
    (shard / "COMPLETE.json").write_text(json.dumps(marker))
    lines = [json.loads(line) for line in (root / "manifest.jsonl").read_text().splitlines()]
    (root / "manifest.jsonl").write_text(
        "".join(json.dumps(fake(r) if r["id"] == sample_id else r) + "\n" for r in lines)
    )


def test_dataset_json_records_the_variant_and_its_guarantee(reference):
    description = json.loads((reference / "dataset.json").read_text())
    assert description["variant"] == VARIANT
    assert description["determinism"] == {"guarantee": BYTE_IDENTICAL, "basis": GUARANTEE_BASIS[BYTE_IDENTICAL]}


def test_info_says_the_guarantee(reference):
    from pipeline.check.info import dataset_info

    assert f"{VARIANT} (byte-identical re-renders)" in dataset_info(str(reference)).lines()[0]


def test_the_weakest_guarantee_wins():
    assert weakest_guarantee(BYTE_IDENTICAL, WITHIN_NOISE) == WITHIN_NOISE
    assert weakest_guarantee(BYTE_IDENTICAL, None) == BYTE_IDENTICAL
    assert weakest_guarantee(WITHIN_NOISE, "something else") == WITHIN_NOISE


@pytest.mark.slow
def test_a_resume_of_a_within_noise_dataset_rewrites_nothing_that_verifies(tmp_path, reference):
    """A lost render is rendered again; a lost maps file is written again and its renders,
    valid, are kept (they depend on the texture maps, not on the screen-space maps); nothing
    else of the shard is rewritten; the recorded guarantee stays the weaker one."""
    out = _copy(reference, tmp_path, WITHIN_NOISE)
    shard = out / SHARD
    for name in ("COMPLETE.json", f"{LOST}.render.exr", "m000003.maps.exr"):
        (shard / name).unlink()
    (out / "manifest.jsonl").unlink()
    before = _files(out)
    summary = build(str(SMOKE), str(out), cluster=ClusterOptions(workers=0))
    assert (summary.rendered, summary.skipped) == (1, 15)
    after = _files(out)
    rewritten = {rel for rel in before if after.get(rel) != before[rel]}
    assert rewritten == {"dataset.json", f"{SHARD}/{LOST}.json"}, rewritten
    assert {rel for rel in after if rel not in before} == {
        "manifest.jsonl",
        f"{SHARD}/COMPLETE.json",
        f"{SHARD}/{LOST}.render.exr",
        f"{SHARD}/m000003.maps.exr",
    }
    assert _sha(shard / "m000003.maps.exr") == _sha(reference / SHARD / "m000003.maps.exr")
    description = json.loads((out / "dataset.json").read_text())
    assert description["determinism"]["guarantee"] == WITHIN_NOISE  # the renders kept promise no more
    assert validate(str(out)).ok


@pytest.mark.slow
@pytest.mark.parametrize("guarantee", [BYTE_IDENTICAL, WITHIN_NOISE])
def test_a_repaired_render_that_differs_from_the_lost_copy_is_recorded_everywhere(tmp_path, reference, guarantee):
    """A re-render with other bytes than its lost copy is a new valid sample, not corruption:
    its record file, the shard marker and the manifest all list the new file, validation
    passes, nothing else is rewritten, and the repair says what happened under the dataset's
    guarantee."""
    out = _copy(reference, tmp_path, guarantee)
    _give_lost_copy_another_digest(out, LOST)
    (out / SHARD / f"{LOST}.render.exr").unlink()
    before = _files(out)
    report_before, after, actions = repair(str(out))
    assert [p.kind for p in report_before.problems] == ["missing_file"]
    assert after.ok, [p.message for p in after.problems]
    new_digest = _sha(out / SHARD / f"{LOST}.render.exr")
    assert new_digest != FAKE_DIGEST
    assert [_render_digests(r) for r in _every_copy(out, LOST)] == [[new_digest]] * 3
    [rerender] = [a for a in actions if a.action == "rerender"]
    if guarantee == WITHIN_NOISE:
        assert "a new render, not the lost copy's bytes (within-noise dataset" in rerender.message
    else:
        assert (
            "differ from the lost copy's recorded SHA-256 although this dataset's re-renders are "
            "byte-identical" in rerender.message
        )
    changed = {rel for rel, stamp in _files(out).items() if before.get(rel) != stamp}
    assert changed == {
        "dataset.json",
        "manifest.jsonl",
        f"{SHARD}/COMPLETE.json",
        f"{SHARD}/{LOST}.json",
        f"{SHARD}/{LOST}.render.exr",
    }, changed


@pytest.mark.slow
def test_a_repaired_render_of_a_byte_identical_dataset_says_it_has_the_lost_bytes(tmp_path, reference):
    out = _copy(reference, tmp_path)
    (out / SHARD / f"{LOST}.render.exr").unlink()
    _before, after, actions = repair(str(out))
    assert after.ok
    [rerender] = [a for a in actions if a.action == "rerender"]
    assert rerender.message.endswith("byte-identical to the lost copy")
    assert _sha(out / SHARD / f"{LOST}.render.exr") == _sha(reference / SHARD / f"{LOST}.render.exr")


def test_repair_renders_with_the_recorded_variant_and_refuses_one_it_cannot_use(tmp_path, reference):
    """The spec says ``auto``, which here picks llvm; the dataset says it was rendered with
    cuda. A repair must re-render with the dataset's variant, not ``auto`` resolved anew:
    on a machine without a GPU it refuses, names the variant, and changes nothing."""
    from pipeline.render.mitsuba_env import cuda_works

    if cuda_works():
        pytest.skip("this machine can use the cuda variant: the refusal cannot happen here")
    out = _copy(reference, tmp_path)
    path = out / "dataset.json"
    description = json.loads(path.read_text())
    path.write_text(json.dumps(dict(description, variant="cuda_ad_rgb")))
    (out / SHARD / f"{LOST}.render.exr").unlink()
    before = _files(out)
    with pytest.raises(
        SetupError, match="rendered with Mitsuba variant cuda_ad_rgb, which cannot be used here.*nothing was changed"
    ):
        repair(str(out))
    assert _files(out) == before
