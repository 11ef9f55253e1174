"""The specs `plan` names as cheaper for training are held to the downstream study that found
them: the studied spec unchanged since (its digest), the cheaper spec the same samples at the
level the study chose, the verdict the report's own, and `plan` saying so."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from cli import main
from pipeline.bench.training_specs import CHEAPER_FOR_TRAINING
from pipeline.check.snapshot import spec_differences
from pipeline.dataset.spec_file import parse_spec, spec_digest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("entry", CHEAPER_FOR_TRAINING, ids=lambda e: e.cheaper)
def test_the_entry_is_its_studys_decision(entry):
    studied, cheaper = parse_spec(REPO / entry.studied), parse_spec(REPO / entry.cheaper)
    assert spec_digest(studied) == entry.digest, f"{entry.studied} changed since its study: study it again"
    differ = {f"{section}.{key}" for section, key, _old, _new in spec_differences(studied, cheaper)}
    assert differ == {"render.spp", "dataset.name"}, differ
    result = json.loads((REPO / entry.report).with_name("downstream.json").read_text())
    assert result["decision"]["ship"] and result["decision"]["level"] == cheaper.render.spp
    assert result["decision"]["verdict"] == entry.verdict
    assert entry.verdict in (REPO / entry.report).read_text()
    assert entry.verdict in (REPO / entry.cheaper).read_text().replace("\n# ", " ")  # quoted in its comments


@pytest.mark.parametrize("entry", CHEAPER_FOR_TRAINING, ids=lambda e: e.cheaper)
def test_plan_names_the_cheaper_spec(entry):
    done = CliRunner().invoke(main, ["plan", str(REPO / entry.studied), "--no-timing", "--json"])
    assert done.exit_code == 0, done.output
    notes = json.loads(done.output)["notes"]
    assert any(entry.cheaper in note and entry.report in note for note in notes), notes
    other = CliRunner().invoke(main, ["plan", str(REPO / entry.cheaper), "--no-timing", "--json"])
    assert not any("for training" in note for note in json.loads(other.output)["notes"])
