"""An option that feeds a spec field or another request's field allows what that field
allows, says so in its help, and a value it refuses is refused naming the option as the user
typed it (``--shard-size``), never the field it feeds (``dataset.shard_size``): at the edges
of the declared range, and where the field's rule depends on other values (the spec's
lightings, the study's ladder)."""

from __future__ import annotations

import math

import click
import pytest
from click.testing import CliRunner

import cli
from pipeline.bench.command import BenchRequest
from pipeline.dataset.spec import MAX_SHARD_RENDERS, DatasetSection, LightingSection, MaterialsSection, StorageSection
from pipeline.dataset.spec_file import parse_spec
from pipeline.fields import FieldError, declared
from pipeline.fields.rules import Float, Int, Optional
from pipeline.render.settings import RenderSettings
from pipeline.run.cluster.options import ClusterOptions
from pipeline.ui.command import reworded
from pipeline.ui.options import FieldType
from support import SMOKE

#: The classes whose fields a command's options feed: the spec's sections, the renderer's
#: settings, the cluster's options.
FED = (DatasetSection, MaterialsSection, LightingSection, StorageSection, RenderSettings, ClusterOptions)
#: What each command needs besides the option tried (its operands, a required --out).
NEEDS = {
    "bench": lambda tmp: [SMOKE],
    "plan": lambda tmp: [SMOKE, "--no-timing"],
    "study": lambda tmp: [SMOKE, "--out", str(tmp / "out")],
    "build": lambda tmp: [SMOKE, "--out", str(tmp / "out")],
    "render": lambda tmp: ["--out", str(tmp / "out" / "ball.exr")],
}


def inner(rule):
    return rule.rule if isinstance(rule, Optional) else rule


def fed_field(rule):
    """The (class, field) whose declaration ``rule`` is, or None."""
    for cls in FED:
        for name, f in declared(cls).items():
            if inner(f.metadata["rule"]) is inner(rule):
                return cls, name
    return None


def feeding_options():
    """(command, option) of every option of ``NEEDS``' commands that feeds a field of FED with a
    range of numbers (integers or floats)."""
    found = []
    for command in NEEDS:
        for p in cli.main.commands[command].params:
            if isinstance(p, click.Option) and isinstance(p.type, FieldType) and fed_field(p.type.rule):
                if isinstance(inner(p.type.rule), (Int, Float)):
                    found.append((command, p))
    return found


FEEDING = feeding_options()


def just_outside(command: str, option) -> list:
    """The values just below and above the range ``option`` of ``command`` takes: its declared
    range's, and where a rule between fields narrows it for NEEDS' spec, that rule's edge."""
    rule = inner(option.type.rule)
    if isinstance(rule, Int):
        values = [v for v in (rule.lo - 1, rule.hi + 1) if v not in rule.also]
    else:
        values = [math.nextafter(rule.lo, -math.inf), math.nextafter(rule.hi, math.inf)]
    if (command, option.name) == ("bench", "shard_size"):  # a shard of at most MAX_SHARD_RENDERS renders
        values.append(MAX_SHARD_RENDERS // parse_spec(SMOKE).dataset.lights_per_material + 1)
    return values


def test_the_options_that_feed_a_spec_or_cluster_field_are_found():
    names = {(command, p.name) for command, p in FEEDING}
    for expected in [
        ("bench", "shard_size"),
        ("bench", "resolution"),
        ("bench", "spp"),
        ("study", "resolution"),
        ("plan", "workers"),
        ("build", "workers"),
        ("build", "jobs"),
        ("render", "spp"),
    ]:
        assert expected in names, expected


@pytest.mark.parametrize("command, option", FEEDING, ids=[f"{c} {p.opts[0]}" for c, p in FEEDING])
def test_an_option_allows_what_the_field_it_feeds_allows_and_refuses_by_its_own_name(tmp_path, command, option):
    cls, name = fed_field(option.type.rule)
    field_rule = inner(declared(cls)[name].metadata["rule"])
    rule = inner(option.type.rule)
    allowed = " ".join(option.help.split()).partition("Allowed: ")[2]  # "[0, 1e+06]", or with a unit before it
    assert field_rule.brief in allowed, option.help
    for value in just_outside(command, option):
        typed = repr(value) if isinstance(value, float) else str(value)
        args = [command, *NEEDS[command](tmp_path), option.opts[0], typed]
        result = CliRunner().invoke(cli.main, args)
        assert result.exit_code == 2, (args, result.output)
        assert result.output.startswith(f"error: {option.opts[0]}: {typed} is not allowed; "), (args, result.output)
        if value in (rule.lo - 1, rule.hi + 1) or not isinstance(value, int):  # the declared range's edge
            assert field_rule.allowed in result.output, (args, result.output)
        section = getattr(cls, "SECTION", None)  # a spec section's or the renderer's spelling of the field
        assert section is None or f"{section}.{name}" not in result.output, (args, result.output)
        assert not (tmp_path / "out").exists()


# --------------------------------------------------------------------------- rules that depend on other values


def test_bench_shard_size_refused_by_the_spec_lightings_names_the_option(tmp_path):
    lights = parse_spec(SMOKE).dataset.lights_per_material
    too_many = MAX_SHARD_RENDERS // lights + 1  # within the declared range, too many renders for one shard
    assert too_many <= inner(declared(DatasetSection)["shard_size"].metadata["rule"]).hi
    result = CliRunner().invoke(cli.main, ["bench", SMOKE, "--shard-size", str(too_many)])
    assert result.exit_code == 2, result.output
    assert result.output.startswith(f"error: --shard-size: {too_many} is not allowed; "), result.output
    assert f"at most {MAX_SHARD_RENDERS // lights} " in result.output, result.output
    assert "dataset.shard_size" not in result.output, result.output
    help_text = " ".join(next(p for p in cli.main.commands["bench"].params if p.name == "shard_size").help.split())
    assert f"at most {MAX_SHARD_RENDERS} renders" in help_text and "lights_per_material" in help_text, help_text


@pytest.mark.parametrize("name", ["renders", "shard_size", "resolution", "spp"])
def test_bench_options_at_the_ends_of_their_range_are_taken_or_refused_by_their_own_name(name):
    from pipeline.bench.build_bench import bench_spec

    rule = inner(declared(BenchRequest)[name].metadata["rule"])
    for value in (rule.lo, rule.hi):
        request = BenchRequest(spec=SMOKE, **{name: value})
        try:
            spec = bench_spec(request)
        except FieldError as exc:
            words = str(reworded(BenchRequest)(exc))
            assert words.startswith(f"--{name.replace('_', '-')}: {value} is not allowed; "), words
        else:
            assert spec.dataset.n_renders >= 1


def test_bench_scale_size_the_spec_cannot_hold_is_refused_as_scale_before_anything_runs(tmp_path):
    out = tmp_path / "scale"
    top = inner(declared(BenchRequest)["scale"].metadata["rule"]).hi
    lights = parse_spec(SMOKE).dataset.lights_per_material
    result = CliRunner().invoke(cli.main, ["bench", SMOKE, "--scale", f"{2 * lights},{top}", "--out", str(out)])
    assert result.exit_code == 2, result.output
    assert result.output.startswith(f"error: --scale: {top} is not allowed; "), result.output
    assert "dataset.materials" in result.output  # what it would make of the spec, as the spec names it
    assert not out.exists()


def reference_spp_help() -> str:
    option = next(p for p in cli.main.commands["study"].params if p.name == "reference_spp")
    return " ".join(option.help.split())


def test_study_reference_spp_help_says_what_its_least_value_depends_on():
    text = reference_spp_help()
    assert "--ladder" in text and "render.spp" in text and "even" in text, text


@pytest.mark.parametrize("ladder", [(4, 8), (2, 64)])
def test_study_reference_spp_refusal_names_the_ladder_and_the_spec_spp_with_their_values(tmp_path, ladder):
    spp = parse_spec(SMOKE).render.spp
    least = 2 * max(*ladder, spp)
    out = tmp_path / "out"
    args = ["study", SMOKE, "--out", str(out), "--ladder", ",".join(map(str, ladder))]
    result = CliRunner().invoke(cli.main, [*args, "--reference-spp", str(least - 2)])
    assert result.exit_code == 2, result.output
    assert result.output.startswith(
        f"error: --reference-spp: {least - 2} is not allowed; an even integer from {least} to "
    ), result.output
    assert f"--ladder ({max(ladder)})" in result.output and f"render.spp ({spp})" in result.output, result.output
    assert not out.exists()
