"""Parts: a class of fields that several requests share is declared once and nested
(``pipeline.fields.part``), never copied field by field.

- a part's fields are the command's options, spelled by their own names, with the part's
  rules: one declaration, read by the command line and by Python;
- a request built from Python takes a part as an instance or a dict of its fields, and
  refuses a bad value inside it naming the field, as the command line does;
- a name declared twice over a request and its parts is refused when the command is made;
- no request copies the fields of a class that it could nest.
"""

from __future__ import annotations

import dataclasses

import click
import pytest
from test_cli_usage import COMMANDS, SMOKE, invoke, refusal

from pipeline.fields import Checked, FieldError, declared, field, flattened, part, parts
from pipeline.fields.rules import Int
from pipeline.neural.config import NetworkPart
from pipeline.render.command import RenderRequest
from pipeline.render.parts import MaterialPart, SunSkyPart
from pipeline.render.settings import RenderSettings
from pipeline.run.cluster.options import ClusterOptions
from pipeline.run.request import BuildRequest
from pipeline.ui.command import params_of, request_of

#: Which part each command nests, and which class it is.
NESTED = {
    "build": {"cluster_options": ClusterOptions},
    "render": {"material": MaterialPart, "sun_sky": SunSkyPart, "settings": RenderSettings},
    "infer": {"network": NetworkPart, "material": MaterialPart, "sun_sky": SunSkyPart},
    "evaluate": {"network": NetworkPart},
    "export": {"network": NetworkPart},
}


@pytest.mark.parametrize("name", sorted(NESTED))
def test_a_command_nests_its_parts(name):
    command = dict(COMMANDS)[name]
    assert parts(command.request_cls) == NESTED[name]
    options = {p.name: p for p in command.params}
    for part_cls in NESTED[name].values():
        for field_name, f in declared(part_cls).items():
            assert field_name in options, f"{name}: {part_cls.__name__}.{field_name} is no option"
            assert options[field_name].type.rule is f.metadata["rule"], "the part's own declaration"
            assert field_name not in declared(command.request_cls), "copied beside the part"


def _rule(f):
    rule = f.metadata["rule"]
    return getattr(rule, "rule", rule)  # a copy made optional (same_as ..., unset=) holds the same rule


def test_no_request_copies_a_part_field_by_field():
    """A request that copies every field of a part class (same_as: the same rules) nests it
    instead. serve's --run and --checkpoint are its own: an optional option, not RUN."""
    part_classes = {cls for _, command in COMMANDS for cls in parts(command.request_cls).values()}
    for name, command in COMMANDS:
        own = declared(command.request_cls)
        for cls in part_classes:
            copied = [n for n, f in declared(cls).items() if n in own and _rule(own[n]) is _rule(f)]
            assert len(copied) < len(declared(cls)), f"{name}: copies {cls.__name__} instead of nesting it"


def test_python_builds_a_part_from_a_dict_or_an_instance(tmp_path):
    out = str(tmp_path / "o")
    by_dict = BuildRequest(spec=SMOKE, out=out, cluster_options={"workers": 0})
    by_instance = BuildRequest(spec=SMOKE, out=out, cluster_options=ClusterOptions(workers=0))
    assert by_dict == by_instance and by_dict.cluster_options.workers == 0
    assert BuildRequest(spec=SMOKE, out=out).cluster_options == ClusterOptions()


def test_a_bad_value_in_a_part_is_refused_alike(tmp_path):
    out = str(tmp_path / "o")
    with pytest.raises(FieldError) as info:
        BuildRequest(spec=SMOKE, out=out, cluster_options={"workers": -3})
    assert info.value.name == "workers"
    message = refusal(invoke("build", SMOKE, "--out", out, "--workers", "-3"))
    assert message.startswith("--workers: ") and message.split(": ", 1)[1] == str(info.value).split(": ", 1)[1]
    with pytest.raises(FieldError, match="cluster_options: .* a ClusterOptions or a dict of its fields"):
        BuildRequest(spec=SMOKE, out=out, cluster_options={"no_such_field": 1})


def test_render_and_infer_refuse_a_part_value_alike(tmp_path):
    """The sun of `render` and of `infer` is one declaration: the same words for the same value."""
    with pytest.raises(FieldError) as info:
        RenderRequest(out=str(tmp_path / "x.exr"), sun_sky={"elevation": 95.0})
    for words in (
        ["render", "--out", str(tmp_path / "x.exr")],
        ["infer", str(tmp_path), "--out", str(tmp_path / "y.exr")],
    ):
        message = refusal(invoke(*words, "--elevation", "95"))
        assert message == "--elevation: 95 is not allowed; " + info.value.allowed, message


def test_a_rendered_record_keeps_its_flat_names(tmp_path):
    """An EXR's ``request`` record is one flat table (its parts' fields among the others), as
    before the parts: readers of old and new renders see the same keys in the same order."""
    record = RenderRequest(out=str(tmp_path / "x.exr")).record()
    assert list(record)[:9] == [
        "diffuse",
        "specular",
        "roughness",
        "normal",
        "svbrdf",
        "svbrdf_colorspace",
        "elevation_deg",
        "azimuth_deg",
        "turbidity",
    ]
    assert "material" not in record and "sun_sky" not in record and "out" not in record


def test_a_rule_between_a_request_and_its_part_names_the_option(tmp_path):
    message = refusal(invoke("build", SMOKE, "--out", str(tmp_path / "o"), "--print-job-script"))
    assert message.startswith("--print-job-script: needs batch jobs; give --cluster slurm"), message


def test_the_command_line_makes_the_request_python_does(tmp_path):
    command = dict(COMMANDS)["build"]
    out = str(tmp_path / "o")
    ctx = command.make_context("build", [SMOKE, "--out", out, "--workers", "0", "--cluster", "local"])
    values = {k: v for k, v in ctx.params.items() if k != "as_json" and not k.startswith("renamed_")}
    made = request_of(BuildRequest, values)
    assert made == BuildRequest(spec=SMOKE, out=out, cluster_options=ClusterOptions(workers=0, cluster="local"))


def test_a_name_declared_twice_is_refused_when_the_command_is_made():
    @dataclasses.dataclass(frozen=True)
    class Twice(Checked):
        workers: int = field(1, rule=Int(0, 4), doc="Clashes with the part's.")
        cluster_options: ClusterOptions = part(ClusterOptions, doc="The part.")

    with pytest.raises(TypeError, match="workers"):
        flattened(Twice)
    with pytest.raises(TypeError, match="workers"):
        params_of(Twice)


def test_every_part_is_a_class_of_declared_fields():
    for name, command in COMMANDS:
        for part_name, cls in parts(command.request_cls).items():
            assert issubclass(cls, Checked) and declared(cls), f"{name}: {part_name}"
            assert all(isinstance(p, click.Parameter) for p in params_of(cls))
