"""The command line reads each parameter's one declaration (pipeline.fields): an option made
from a dataclass field has the field's default and its rule, and refuses a value in the
same words as the dataclass does."""

from __future__ import annotations

import dataclasses

import click
import pytest
from click.testing import CliRunner

import cli
from pipeline.fields import FieldError, declared, default_of
from pipeline.fields.rules import Optional
from pipeline.neural.config import TrainConfig
from pipeline.render.parts import MaterialPart, SunSkyPart
from pipeline.render.settings import RenderSettings
from pipeline.run.cluster.options import ClusterOptions
from pipeline.ui.command import label_for
from pipeline.ui.options import FieldType


def options_of(command: str) -> dict[str, click.Option]:
    return {p.name: p for p in cli.main.commands[command].params if isinstance(p, click.Option)}


def default_value(option: click.Option):
    """The value an option gives when it is not on the command line (a default typed as
    text, "0.5,0.5,0.5", parsed as the command line is)."""
    if isinstance(option.default, str) and isinstance(option.type, FieldType):
        return option.type.convert(option.default, option, None)
    return option.default


def rule_of(option: click.Option):
    """The rule an option is checked by (an optional one's inner rule: None is "unset")."""
    rule = option.type.rule if isinstance(option.type, FieldType) else None
    return rule.rule if isinstance(rule, Optional) else rule


@pytest.mark.parametrize("name", [n for n in declared(TrainConfig) if n not in ("dataset", "out")])
def test_every_train_config_field_is_an_option_with_its_default_and_rule(name):
    option = options_of("train").get(name)
    assert option is not None, f"TrainConfig.{name} has no option of `train`"
    field = declared(TrainConfig)[name]
    assert default_value(option) == default_of(field), f"--{name}: the command's default is not TrainConfig's"
    if not option.is_flag:
        assert option.type.rule is field.metadata["rule"], f"--{name} is not checked by TrainConfig's rule"


@pytest.mark.parametrize("command", ["render", "scene", "bench", "study"])
def test_render_settings_options_carry_the_settings_default_and_rule(command):
    fields = declared(RenderSettings)
    found = {name: option for name, option in options_of(command).items() if name in fields}
    assert "resolution" in found, command
    for name, option in found.items():
        assert rule_of(option) is fields[name].metadata["rule"], f"{command} --{name}"
        if option.default is None:  # the spec's value
            assert "[default: the spec's" in option.help, f"{command} --{name}"
        else:
            assert default_value(option) == default_of(fields[name]), f"{command} --{name}"


@pytest.mark.parametrize("command", ["render", "infer"])
def test_render_and_infer_take_the_parts_declarations(command):
    fields = {**declared(MaterialPart), **declared(SunSkyPart)}
    options = options_of(command)
    for name in ("diffuse", "specular", "roughness", "normal", "svbrdf", "elevation", "azimuth", "turbidity"):
        assert options[name].type.rule is fields[name].metadata["rule"], f"{command} {name}"
        assert default_value(options[name]) == default_of(fields[name]), f"{command} {name}"


# validate --repair's --workers is its own declaration: 0 (in this process) by default, never unset
@pytest.mark.parametrize("command", ["build", "plan", "bench"])
def test_workers_is_declared_once_in_cluster_options(command):
    option = options_of(command)["workers"]
    assert option.type.rule is declared(ClusterOptions)["workers"].metadata["rule"]


def test_build_cluster_options_are_the_dataclass_fields():
    options = options_of("build")
    for name, field in declared(ClusterOptions).items():
        assert name in options, f"ClusterOptions.{name} has no option of `build`"
        assert default_value(options[name]) == default_of(field), name


@pytest.mark.parametrize(
    "args, config",
    [
        (["--epochs", "0"], {"epochs": 0}),
        (["--lr", "0"], {"lr": 0}),  # the same value as typed: a refusal echoes it so
        (["--loss", "l3"], {"loss": "l3"}),
        (["--resolution", "50"], {"resolution": 50}),
        (["--loader-workers", "65"], {"loader_workers": 65}),
    ],
)
def test_a_refused_option_reads_as_the_dataclass_refusal(args, config, tmp_path):
    with pytest.raises(FieldError) as refused:
        dataclasses.replace(TrainConfig(dataset="d", out="o"), **config)
    result = CliRunner().invoke(cli.main, ["train", str(tmp_path / "d"), "--out", str(tmp_path / "run"), *args])
    spelled = refused.value.labelled(label_for(TrainConfig))  # the library names the field; the CLI spells it
    assert result.exit_code == 2 and f"error: {spelled}" in result.output, result.output
    assert not (tmp_path / "run").exists()


def test_a_render_option_is_refused_in_the_spec_words(tmp_path):
    with pytest.raises(FieldError) as refused:
        RenderSettings(spp=0)
    result = CliRunner().invoke(cli.main, ["render", "--spp", "0", "--out", str(tmp_path / "x.exr")])
    assert result.exit_code == 2, result.output
    assert "--spp: " + str(refused.value).split(": ", 1)[1] in result.output, result.output
    assert not list(tmp_path.iterdir())
