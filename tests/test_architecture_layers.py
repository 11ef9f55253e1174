"""The layer contract (pyproject.toml, ``[tool.shaderball.layers]``) holds, with no exceptions.

scripts/layers.py reads the contract and the code (with ``ast``); this file fails on any
import the contract does not allow, on a contract that is not a strict order of layers, and
on a docstring paragraph or a docs/architecture.md diagram that no longer says what the
contract says (re-run ``python scripts/layers.py --write``).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from support.scripts import script_module

REPO = Path(__file__).resolve().parents[1]
layers = script_module("layers")

CONTRACT = layers.load_contract()


def test_the_contract_is_a_strict_order_of_existing_packages():
    assert layers.contract_problems(CONTRACT) == []


def test_every_package_of_the_project_is_in_the_contract():
    units = layers.layer_of(CONTRACT)
    folders = {
        ".".join(init.parent.relative_to(REPO).parts)
        for root in layers.PROJECT_ROOTS[:-1]
        for init in (REPO / root).rglob("__init__.py")
        if init.parent.parent == REPO or init.parent.parent.name == "pipeline"
    }
    assert folders - set(units) == set()


def test_every_import_is_one_the_contract_allows():
    assert layers.violations(CONTRACT) == []


def test_at_most_nine_layers_of_packages_under_the_cli():
    """Eight stages deep, and one package above them that composes them (pipeline.downstream:
    builds, the pixel study's statistics and the networks); a tenth needs a reason as good."""
    assert list(CONTRACT[-1]) == ["cli"]
    assert len(CONTRACT) - 1 <= 9


def test_the_docstrings_and_the_diagram_say_what_the_contract_says():
    assert layers.stale_paragraphs(CONTRACT) + layers.stale_diagram(CONTRACT) == []


@pytest.mark.parametrize(
    "importer, imported, allowed",
    [
        ("pipeline.check.crosscheck", "pipeline.render.renderer", False),  # imports that once broke the layers stay out
        ("pipeline.publish.writer", "pipeline.run.build", False),
        ("pipeline.dataset.spec", "pipeline.store.exr", False),
        ("pipeline.study.measure", "pipeline.neural.metrics", False),
        ("pipeline.dataset.spec", "pipeline.render.limits", True),
        ("pipeline.dataset.spec", "pipeline.render.renderer", False),
        ("pipeline.store.exr", "pipeline.render.mitsuba_env", False),  # back up a layer
        ("pipeline.run.build", "pipeline.publish.reader", False),  # sideways within a layer
    ],
)
def test_the_check_refuses_what_the_contract_forbids(importer, imported, allowed):
    units, rules = layers.layer_of(CONTRACT), layers.may_import(CONTRACT)
    assert layers.allows(rules[layers.unit_of(importer, units)], imported, units) is allowed


def test_the_docs_name_every_package_and_a_sample_path_that_exists():
    """docs/architecture.md has a row for every package of the contract, and every
    ``pipeline.x.y.name`` its sample's path names is a module, or a name one defines."""
    page = layers.ARCHITECTURE_DOC.read_text(encoding="utf-8")
    tree = page.split("## The tree", 1)[1].split("\n## ", 1)[0]
    for unit in layers.layer_of(CONTRACT):
        row = (
            "cli.py"
            if unit == "cli"
            else unit.replace(".", "/") + ("/" if layers.unit_file(unit).name == "__init__.py" else ".py")
        )
        row = "pipeline/` (the root" if unit == "pipeline" else row
        assert f"| `{row}" in tree, f"docs/architecture.md: no row for {unit}"
    path = page.split("## One sample's path through the code", 1)[1].split("\n## ", 1)[0]
    modules = layers.project_modules()
    missing = []
    for dotted in sorted(set(re.findall(r"`((?:pipeline|cli)(?:\.\w+)+)", path))):
        if dotted in modules:
            continue
        module, _, name = dotted.rpartition(".")
        defined = module in modules and re.search(
            rf"^(?:def|class) {name}\b|^{name}\s*[:=]|^    def {name}\b", modules[module].read_text(), re.M
        )
        if not defined:
            missing.append(dotted)
    assert not missing, f"docs/architecture.md names what does not exist: {missing}"
