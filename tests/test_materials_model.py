"""The material model as a choice: `materials.model` in a spec, `shaderball render --model`, what records say.

The default ("shaderball") must leave every dataset built before the choice existed as it
was: the same spec digest, no new key in records or render files. "deschaintre2018" is
recorded in both, and validation holds records to it.
"""

import json
import os
from pathlib import Path

import pytest
from click.testing import CliRunner

from cli import main
from materials.brdf_ref import MODELS
from pipeline.check.validate import validate
from pipeline.dataset.spec_file import parse_spec, parse_spec_text, spec_digest
from pipeline.dataset.spec_rules import SpecError
from pipeline.errors import ShaderballError
from pipeline.render.command import RenderRequest
from pipeline.run.build import build
from pipeline.run.cluster.options import ClusterOptions
from pipeline.store.exr import read_exr

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"
#: manifests/smoke.toml's digest as computed before materials.model existed (measured on the
#: commit before it): datasets built then must keep validating and resuming.
SMOKE_DIGEST_BEFORE_THE_MODEL = "fbe79ed45c42f3bc064fb3250a8204252560721f63b64717c33c02306007c878"

TINY = """
[dataset]
name = "tiny"
seed = 5
materials = 1
lights_per_material = 1
svbrdf_fraction = 0.0
shard_size = 1

[materials]
roughness = [0.08, 0.08]
metal_probability = 1.0
texture_resolution = 16
{model}

[render]
resolution = 16
spp = 2
"""


def test_spec_takes_the_model_and_keeps_old_digests():
    assert spec_digest(parse_spec(SMOKE)) == SMOKE_DIGEST_BEFORE_THE_MODEL, (
        "the default model must not change the digest of a spec that does not name it "
        "(if manifests/smoke.toml itself changed, update the pinned digest)"
    )
    plain = parse_spec_text(TINY.format(model=""))
    explicit = parse_spec_text(TINY.format(model='model = "shaderball"'))
    floored = parse_spec_text(TINY.format(model='model = "deschaintre2018"'))
    assert plain.materials.model == "shaderball" and floored.materials.model == "deschaintre2018"
    assert plain == explicit and spec_digest(plain) == spec_digest(explicit)
    assert spec_digest(floored) != spec_digest(plain)


def test_bad_model_in_a_spec_is_refused_naming_field_value_and_choices(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(TINY.format(model='model = "floored"'))
    with pytest.raises(SpecError) as info:
        parse_spec(path)
    message = str(info.value)
    assert message.startswith(f"{path}: materials.model: "), message
    assert '"floored" is not allowed' in message and '"shaderball", "deschaintre2018"' in message
    assert info.value.exit_code == 2
    out = tmp_path / "never"
    result = CliRunner().invoke(main, ["build", str(path), "--out", str(out), "--workers", "0"])
    assert result.exit_code == 2, result.output
    assert "materials.model" in result.output and "floored" in result.output
    assert not out.exists()


def test_render_model_option_is_checked_before_anything_is_written(tmp_path):
    out = tmp_path / "ball.exr"
    result = CliRunner().invoke(main, ["render", "--model", "floored", "--out", str(out)])
    assert result.exit_code == 2, result.output
    assert "--model" in result.output and "floored" in result.output
    assert all(m in result.output for m in MODELS)
    assert not out.exists()
    # The library names the field as its class does (the render settings, a spec's [render]);
    # the command line spells it --model.
    with pytest.raises(
        ShaderballError,
        match=r'^render.model: "floored" is not allowed; one of "shaderball", "deschaintre2018"',
    ) as info:
        RenderRequest(settings={"model": "floored"}, out=str(out))
    assert info.value.exit_code == 2 and not out.exists()


def _records(root: Path) -> list[dict]:
    return [json.loads(line) for line in (root / "manifest.jsonl").read_text().splitlines()]


def _render_meta(root: Path, record: dict) -> dict:
    path = next(f["path"] for f in record["files"] if f["role"] == "render")
    return read_exr(os.path.join(root, *path.split("/"))).meta


@pytest.fixture(scope="module")
def tiny_builds(tmp_path_factory):
    """The same one-render dataset built with each model."""
    roots = {}
    for model in MODELS:
        folder = tmp_path_factory.mktemp(model)
        spec = folder / "spec.toml"
        spec.write_text(TINY.format(model=f'model = "{model}"'))
        build(str(spec), str(folder / "data"), cluster=ClusterOptions(workers=0))
        roots[model] = folder / "data"
    return roots


def test_records_and_render_files_name_the_model_only_when_not_the_default(tiny_builds):
    default, floored = tiny_builds["shaderball"], tiny_builds["deschaintre2018"]
    (record,) = _records(default)
    assert "model" not in record["render"] and "model" not in _render_meta(default, record)
    (record_f,) = _records(floored)
    assert record_f["render"]["model"] == "deschaintre2018"
    assert _render_meta(floored, record_f)["model"] == "deschaintre2018"
    # Same material, same seeds: only the model differs, and the smooth metal (r = 0.08) loses light
    # (the image mean includes the rest of the scene, which does not change).
    assert record_f["seeds"] == record["seeds"] and record_f["material"] == record["material"]
    assert record_f["stats"]["mean"] < 0.9 * record["stats"]["mean"]


def test_validation_holds_records_to_the_model(tiny_builds):
    for root in tiny_builds.values():
        assert validate(str(root)).ok
    root = tiny_builds["deschaintre2018"]
    (path,) = list((root / "shards").rglob("*_l0.json"))
    manifest = root / "manifest.jsonl"
    record = json.loads(path.read_text())
    del record["render"]["model"]  # a record that says the default model
    path.write_text(json.dumps(record, sort_keys=True) + "\n")
    manifest.write_text(json.dumps(record, sort_keys=True) + "\n")
    report = validate(str(root))
    assert not report.ok
    assert "render.model" in str(report.problems), report.problems
