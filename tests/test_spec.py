"""Specs: the shipped manifests parse; every bad field is refused by name, value and range;
the canonical form round-trips; the reference page matches the code."""

from __future__ import annotations

import dataclasses
import importlib
import json
import subprocess
import sys
import textwrap

import pytest

from materials.errors import MaterialError
from pipeline.dataset.spec import (
    FALLBACK_LIGHT_SCHEMES,
    FALLBACK_SVBRDF_FAMILIES,
    MAP_LAYERS,
    SUN_FORMS,
    UNIFORM_FIELDS,
    DatasetSection,
    DatasetSpec,
    LightingSection,
    MaterialsSection,
    RenderSection,
    svbrdf_family_names,
)
from pipeline.dataset.spec_file import (
    parse_spec,
    parse_spec_text,
    reference_markdown,
    reference_rows,
    spec_digest,
    spec_to_dict,
    spec_to_toml,
)
from pipeline.dataset.spec_rules import SpecError
from pipeline.errors import ShaderballError
from pipeline.fields import FieldError
from support import PAPER, REPO, SMOKE

MINIMAL = '[dataset]\nname = "tiny"\nseed = 7\nmaterials = 4\n'


def write_spec(tmp_path, text: str, name: str = "spec.toml") -> str:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return str(path)


def spec_with(tmp_path, section: str, key: str, value_toml: str) -> str:
    """A valid minimal spec with ``key = value_toml`` set in ``section``."""
    dataset = {"name": '"tiny"', "seed": "7", "materials": "4"}
    tables: dict[str, dict[str, str]] = {"dataset": dataset}
    tables.setdefault(section, {})[key] = value_toml
    text = "".join(f"[{s}]\n" + "".join(f"{k} = {v}\n" for k, v in t.items()) + "\n" for s, t in tables.items())
    return write_spec(tmp_path, text)


# --------------------------------------------------------------------------- shipped specs


def test_smoke_manifest_parses_as_described():
    spec = parse_spec(SMOKE)
    assert spec.dataset.name == "smoke"
    assert (spec.dataset.materials, spec.dataset.lights_per_material) == (8, 2)
    assert 64 <= spec.render.resolution <= 128
    assert spec.render.spp <= 32
    assert spec.dataset.shard_size == 2
    assert spec.dataset.n_svbrdf == 4


def test_paper_manifest_matches_the_paper():
    spec = parse_spec(PAPER)
    assert spec.dataset.materials == 10_000
    assert spec.dataset.lights_per_material == 5
    assert spec.dataset.n_renders == 50_000
    assert spec.render.resolution == 400
    assert spec.render.spp == 150
    assert spec.dataset.svbrdf_fraction == 0.5
    assert spec.dataset.n_svbrdf == 5_000
    assert spec.lighting.scheme == "uniform_hemisphere"


def test_minimal_spec_takes_documented_defaults():
    spec = parse_spec_text(MINIMAL)
    assert spec == DatasetSpec(DatasetSection(name="tiny", seed=7, materials=4))
    assert spec.dataset.version == "1"
    assert spec.dataset.lights_per_material == 5
    assert spec.dataset.svbrdf_fraction == 0.5
    assert spec.dataset.shard_size == 20
    assert spec.render == RenderSection(resolution=400, spp=150, max_depth=8, integrator="path", variant="auto")
    assert spec.storage.compression == "zip"
    assert spec.storage.layers == MAP_LAYERS
    assert spec.storage.texture_maps is True and spec.storage.maps_half is True
    assert spec.lighting.turbidity == (1.0, 10.0)
    assert spec.materials.svbrdf_families == svbrdf_family_names()
    assert spec.materials.svbrdf_folders == ()


# --------------------------------------------------------------------------- bad fields

# (section, key, value as TOML, text the message must show for the value, text of the
# allowed range that must appear)
BAD_FIELDS = [
    ("dataset", "name", '"Bad Name"', '"Bad Name"', "a-z, 0-9, _ and -"),
    ("dataset", "name", '""', '""', "1 to 64 characters"),
    ("dataset", "seed", "-1", "-1", "an integer from 0 to 9223372036854775807"),
    ("dataset", "seed", '"42"', '"42"', "an integer from 0"),
    ("dataset", "materials", "0", "0", "an integer from 1 to 1000000"),
    ("dataset", "materials", "true", "true", "an integer from 1"),  # bool is not an int
    ("dataset", "materials", "8.0", "8.0", "an integer from 1"),
    ("dataset", "version", '"1 beta"', '"1 beta"', "1 to 32 characters"),
    ("dataset", "lights_per_material", "0", "0", "an integer from 1 to 1000"),
    ("dataset", "svbrdf_fraction", "1.5", "1.5", "a finite number from 0 to 1"),
    ("dataset", "svbrdf_fraction", "nan", "nan", "a finite number from 0 to 1"),
    ("dataset", "svbrdf_fraction", "false", "false", "a finite number"),
    ("dataset", "shard_size", "0", "0", "an integer from 1"),
    ("materials", "roughness", "[0.8, 0.2]", "[0.8, 0.2]", "inverted"),
    ("materials", "diffuse_value_srgb", "[0.0, 1.5]", "[0.0, 1.5]", "0 <= lo <= hi <= 1"),
    ("materials", "dielectric_specular", "[0.5]", "[0.5]", "a pair [lo, hi]"),
    ("materials", "metal_saturation", "0.5", "0.5", "a pair [lo, hi]"),
    ("materials", "metal_probability", "-0.1", "-0.1", "a finite number from 0 to 1"),
    ("materials", "normal_tilt_max_deg", "90", "90", "a finite number from 0 to 80"),
    ("materials", "svbrdf_families", '["no_such_family"]', '["no_such_family"]', 'unknown: "no_such_family"'),
    ("materials", "svbrdf_families", '"tiles"', '"tiles"', "a list of distinct"),
    ("materials", "svbrdf_folders", '["does/not/exist"]', "does/not/exist", "is not a folder"),
    ("materials", "texture_resolution", "8", "8", "an integer from 16 to 4096"),
    ("lighting", "elevation_deg", "[-5, 30]", "[-5, 30]", "0 <= lo <= hi <= 90"),
    ("lighting", "elevation_deg", "[10, 95]", "[10, 95]", "0 <= lo <= hi <= 90"),
    ("lighting", "elevation_deg", "[50, 10]", "[50, 10]", "inverted"),
    ("lighting", "azimuth_deg", "[-100, 300]", "[-100, 300]", "hi - lo <= 360"),
    ("lighting", "turbidity", "[0.5, 3]", "[0.5, 3]", "1 <= lo <= hi <= 10"),
    ("lighting", "turbidity", "[2, inf]", "[2, inf]", "finite"),
    ("lighting", "turbidity", '["2", "3"]', '["2", "3"]', "a pair [lo, hi] of finite numbers"),
    ("lighting", "scheme", '"random"', '"random"', '"uniform_hemisphere"'),
    ("lighting", "sun", '"moon"', '"moon"', '"split", "sunsky"'),
    ("render", "resolution", "8", "8", "an integer from 16 to 4096"),
    ("render", "resolution", "5000", "5000", "an integer from 16 to 4096"),
    ("render", "spp", "0", "0", "an integer from 1 to 65536"),
    ("render", "spp", "16.5", "16.5", "an integer from 1 to 65536"),
    ("render", "max_depth", "0", "0", "or -1"),
    ("render", "max_depth", "-2", "-2", "an integer from 1 to 64"),
    ("render", "integrator", '"volpath"', '"volpath"', 'one of "path"'),
    ("render", "variant", '"gpu"', '"gpu"', '"auto", "llvm", "cuda", "scalar"'),
    ("storage", "compression", '"jpeg"', '"jpeg"', '"none", "zip"'),
    ("storage", "layers", '["diffuse", "albedo"]', '"albedo"', 'unknown: "albedo"'),
    ("storage", "layers", '["normal", "normal"]', '"normal"', 'repeated: "normal"'),
    ("storage", "texture_maps", "1", "1", "true or false"),
    ("storage", "maps_half", '"yes"', '"yes"', "true or false"),
]


@pytest.mark.parametrize(
    "section,key,value,shown,allowed", BAD_FIELDS, ids=[f"{c[0]}.{c[1]}={c[2]}" for c in BAD_FIELDS]
)
def test_bad_field_is_refused_naming_field_value_and_range(tmp_path, section, key, value, shown, allowed):
    path = spec_with(tmp_path, section, key, value)
    with pytest.raises(ShaderballError) as info:
        parse_spec(path)
    message = str(info.value)
    assert message.startswith(f"{path}: {section}.{key}: "), message
    assert shown in message, message
    assert allowed in message, message
    assert "is not allowed" in message
    assert info.value.exit_code == 2
    assert isinstance(info.value, SpecError)
    assert (info.value.section, info.value.field_name) == (section, key)


def test_unknown_key_is_named_with_a_suggestion(tmp_path):
    path = spec_with(tmp_path, "render", "sp", "16")
    with pytest.raises(
        SpecError,
        match=r"render\.sp: unknown key \(value 16\) is not allowed; "
        r"\[render\] takes only: .*spp.*did you mean spp\?",
    ):
        parse_spec(path)


@pytest.mark.parametrize(
    "text, message",
    [
        pytest.param(
            MINIMAL + "light_per_material = 3\n", "dataset.light_per_material: unknown key", id="typo-in-a-key"
        ),
        pytest.param("[render]\nspp = 4\n", r"\[dataset\]: missing; a \[dataset\] section", id="no-dataset-section"),
        pytest.param("render = 4\n" + MINIMAL, r"\[render\]: 4 is not a table", id="section-not-a-table"),
        pytest.param(
            MINIMAL + "[renderer]\nspp = 4\n",
            r"\[renderer\]: unknown section; sections are \[dataset\].*did you mean render\?",
            id="unknown-section",
        ),
        pytest.param(
            MINIMAL + "[materials]\nsvbrdf_families = []\n",
            r"materials\.svbrdf_families: \[\] is not allowed; at least one family .* makes 2 of 4 materials SVBRDF",
            id="svbrdf-share-without-a-source",
        ),
    ],
)
def test_a_malformed_spec_is_refused_naming_what_is_wrong(tmp_path, text, message):
    path = write_spec(tmp_path, text)
    with pytest.raises(SpecError, match=message):
        parse_spec(path)


@pytest.mark.parametrize("missing", ["name", "seed", "materials"])
def test_required_dataset_keys(tmp_path, missing):
    lines = [ln for ln in MINIMAL.splitlines() if not ln.startswith(missing)]
    path = write_spec(tmp_path, "\n".join(lines) + "\n")
    with pytest.raises(SpecError, match=rf"{path}: dataset\.{missing}: missing; required: "):
        parse_spec(path)


def test_invalid_toml_names_the_file(tmp_path):
    path = write_spec(tmp_path, "[dataset\nname = 1\n")
    with pytest.raises(ShaderballError, match=rf"{path}: not valid TOML"):
        parse_spec(path)


def test_missing_file(tmp_path):
    with pytest.raises(ShaderballError, match="spec file: cannot read .*nope.toml.*: No such file"):
        parse_spec(tmp_path / "nope.toml")


def test_no_svbrdf_needs_no_source():
    spec = parse_spec_text(
        MINIMAL.replace("materials = 4", "materials = 4\nsvbrdf_fraction = 0") + "[materials]\nsvbrdf_families = []\n"
    )
    assert spec.dataset.n_svbrdf == 0


def test_too_many_shards_is_refused():
    text = MINIMAL.replace("materials = 4", "materials = 200000\nshard_size = 1")
    with pytest.raises(SpecError, match=r"dataset\.shard_size: 1 is not allowed; at least 2 "):
        parse_spec_text(text, source="big.toml")


def test_error_from_text_names_its_source():
    with pytest.raises(SpecError, match=r"^mine\.toml: render\.spp: 0 is not allowed"):
        parse_spec_text(MINIMAL + "[render]\nspp = 0\n", source="mine.toml")


def test_sections_check_themselves_when_built_in_python():
    # the [render] section is the renderer's settings type: the same words, from pipeline.fields
    with pytest.raises(FieldError, match=r"^render\.spp: 0 is not allowed; an integer from 1"):
        RenderSection(spp=0)
    with pytest.raises(SpecError, match=r"lighting\.turbidity: \[3, 2\]"):
        LightingSection(turbidity=[3, 2])
    section = LightingSection(elevation_deg=[10, 80])
    assert section.elevation_deg == (10.0, 80.0)
    assert all(type(v) is float for v in section.elevation_deg)
    with pytest.raises(dataclasses.FrozenInstanceError):
        section.scheme = "sobol"


def test_the_render_section_is_the_renderers_settings():
    """spec.render is what the renderer takes: the [render] table plus lighting.sun and
    materials.model; -1 (unlimited depth) passes the spec and the renderer alike."""
    from pipeline.render.settings import RenderSettings

    with open(SMOKE, encoding="utf-8") as fh:
        text = fh.read()
    text = text.replace("max_depth = 8", "max_depth = -1").replace('sun = "split"', 'sun = "sunsky"')
    spec = parse_spec_text(text)
    assert type(spec.render) is RenderSettings
    assert (spec.render.sun, spec.render.model, spec.render.max_depth) == ("sunsky", spec.materials.model, -1)
    resolved = spec.render.resolved("llvm_ad_rgb")
    assert resolved.variant == "llvm_ad_rgb" and resolved.max_depth == -1
    assert "sun" not in spec_to_dict(spec)["render"] and "model" not in spec_to_dict(spec)["render"]
    assert parse_spec_text(spec_to_toml(spec)) == spec


# --------------------------------------------------------------------------- folders


def test_relative_svbrdf_folder_is_taken_from_the_spec_folder(tmp_path):
    maps = tmp_path / "maps"
    maps.mkdir()
    (maps / "0001.png").write_bytes(b"")
    spec_dir = tmp_path / "specs"
    spec_dir.mkdir()
    path = write_spec(spec_dir, MINIMAL + '[materials]\nsvbrdf_folders = ["../maps"]\n')
    spec = parse_spec(path)
    assert spec.materials.svbrdf_folders == (str(maps),)
    # The canonical form holds the absolute path, so it parses anywhere.
    assert parse_spec_text(spec_to_toml(spec), base_dir="/") == spec


def test_folder_with_unusual_characters_round_trips(tmp_path):
    maps = tmp_path / 'maps "\U0001f600" \\ \x7f \t end'
    maps.mkdir()
    (maps / "a.png").write_bytes(b"")
    text = MINIMAL + "[materials]\nsvbrdf_folders = [" + json.dumps(str(maps), ensure_ascii=False) + "]\n"
    spec = parse_spec_text(text.replace("\x7f", "\\u007f"))
    assert spec.materials.svbrdf_folders == (str(maps),)
    assert parse_spec_text(spec_to_toml(spec)) == spec


def test_folder_without_map_files_is_refused(tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("x")
    path = write_spec(tmp_path, MINIMAL + '[materials]\nsvbrdf_folders = ["empty"]\n')
    with pytest.raises(SpecError, match=r"materials\.svbrdf_folders: .*holds no \.png file"):
        parse_spec(path)


# --------------------------------------------------------------------------- canonical form


@pytest.mark.parametrize("path", [SMOKE, PAPER])
def test_canonical_round_trip_of_shipped_specs(path):
    spec = parse_spec(path)
    text = spec_to_toml(spec)
    again = parse_spec_text(text, source="snapshot")
    assert again == spec
    assert spec_to_toml(again) == text
    assert spec_digest(again) == spec_digest(spec)


def test_round_trip_of_unusual_values():
    text = MINIMAL + textwrap.dedent("""\
        [lighting]
        elevation_deg = [0.1, 0.30000000000000004]
        azimuth_deg = [-360, 0]
        turbidity = [3, 3]
        [render]
        max_depth = -1
        [storage]
        layers = []
        texture_maps = false
        """)
    spec = parse_spec_text(text)
    assert parse_spec_text(spec_to_toml(spec)) == spec
    assert spec.lighting.elevation_deg == (0.1, 0.30000000000000004)
    assert spec.storage.layers == ()


def test_version_with_punctuation_round_trips():
    spec = parse_spec_text(MINIMAL.replace("tiny", "a_b-c") + 'version = "2.0+rc.1"\n')
    assert parse_spec_text(spec_to_toml(spec)) == spec


def test_same_meaning_same_digest():
    plain = parse_spec_text(MINIMAL)
    explicit = parse_spec_text(
        MINIMAL + "lights_per_material = 5\n"
        "[lighting]\nturbidity = [1, 10]\n"
        '[storage]\nlayers = ["mask", "normal", "roughness", "specular", "diffuse"]\n'
    )
    assert explicit == plain
    assert spec_digest(explicit) == spec_digest(plain)


def test_different_spec_different_digest():
    base = spec_digest(parse_spec_text(MINIMAL))
    assert spec_digest(parse_spec_text(MINIMAL.replace("seed = 7", "seed = 8"))) != base
    assert spec_digest(parse_spec_text(MINIMAL + "[render]\nspp = 151\n")) != base
    assert len(base) == 64 and int(base, 16) >= 0


def test_spec_to_dict_is_plain_data():
    data = spec_to_dict(parse_spec(SMOKE))
    assert json.loads(json.dumps(data)) == data
    assert set(data) == {"dataset", "materials", "scene", "lighting", "render", "storage"}


# --------------------------------------------------------------------------- docs and sync


def test_reference_page_matches_the_code():
    spec_reference = importlib.import_module("scripts.spec_reference")
    with open(spec_reference.PAGE, encoding="utf-8") as fh:
        page = fh.read()
    assert page == spec_reference.render(), f"docs/spec-fields.md is out of date: run {spec_reference.WRITE_COMMAND}"
    assert reference_markdown() in page
    keys = [row[0].strip("`") for row in reference_rows()]
    assert len(keys) == len(set(keys)) >= 25
    for row in reference_rows():
        assert all(cell.strip() for cell in row), row


def test_fallback_lists_match_sky():
    import sky

    assert FALLBACK_LIGHT_SCHEMES == tuple(sky.SCHEMES)
    assert set(SUN_FORMS) == set(sky.SUN_MODES)
    assert LightingSection().sun == sky.DEFAULT_SUN


def test_fallback_families_match_materials():
    import materials

    assert FALLBACK_SVBRDF_FAMILIES == tuple(materials.SVBRDF_FAMILIES)


def test_to_lighting_ranges_builds_sky_ranges():
    import sky

    section = LightingSection(elevation_deg=(10, 70), azimuth_deg=(-90, 90), turbidity=(2, 6), scheme="stratified")
    ranges = section.to_lighting_ranges()
    assert isinstance(ranges, sky.LightingRanges)
    assert (ranges.elevation_deg, ranges.azimuth_deg, ranges.turbidity, ranges.scheme) == (
        (10.0, 70.0),
        (-90.0, 90.0),
        (2.0, 6.0),
        "stratified",
    )


def test_uniform_fields_mirror_materials_uniform_ranges():
    import materials

    names = [f.name for f in dataclasses.fields(materials.UniformRanges)]
    assert list(UNIFORM_FIELDS) == names
    # Same defaults: a spec that leaves [materials] out samples materials' own model.
    assert MaterialsSection().to_uniform_ranges() == materials.UniformRanges()
    section = MaterialsSection(roughness=(0.2, 0.4), normal_tilt_max_deg=80)
    ranges = section.to_uniform_ranges()
    assert ranges.roughness == (0.2, 0.4) and ranges.normal_tilt_max_deg == 80.0


@pytest.mark.parametrize("name", UNIFORM_FIELDS)
def test_uniform_limits_match_materials(name):
    """The spec's bounds are UniformRanges' bounds: the edge passes both, beyond fails both."""
    import materials

    rule = {f.name: f.metadata["rule"] for f in dataclasses.fields(MaterialsSection)}[name]
    is_pair = isinstance(getattr(MaterialsSection(), name), tuple)
    edge = (rule.lo, rule.hi) if is_pair else rule.hi
    beyond = (rule.lo, rule.hi + 0.5) if is_pair else rule.hi + 0.5
    below = (rule.lo - 0.5, rule.hi) if is_pair else rule.lo - 0.5
    MaterialsSection(**{name: edge})
    materials.UniformRanges(**{name: edge})
    for bad in (beyond, below):
        with pytest.raises(SpecError):
            MaterialsSection(**{name: bad})
        with pytest.raises(MaterialError):
            materials.UniformRanges(**{name: bad})


def test_spec_module_is_pure():
    code = (
        "import sys; from pipeline.dataset.spec_file import parse_spec; parse_spec(%r); "
        "bad = [m for m in ('mitsuba', 'drjit', 'dask', 'distributed') if m in sys.modules]; "
        "assert not bad, bad" % SMOKE
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=REPO)
