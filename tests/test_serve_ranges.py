"""Sky's and materials' ranges are declared once, in the domain packages, and every surface
reads them: `shaderball serve`'s page takes its sliders' ranges from /api/info (page.html holds
none of its own), which are the domain's constants; the spec, `shaderball render`'s request,
the server's JSON API and sky's own Light refuse an out-of-range sun elevation with the same
words, built from the same constant. Nothing here starts Mitsuba or a server."""

from __future__ import annotations

from html.parser import HTMLParser
from importlib import resources

import pytest

from materials import ALBEDO_RANGE, ROUGHNESS_RANGE
from pipeline.dataset.spec_file import parse_spec_text
from pipeline.dataset.spec_rules import SpecError
from pipeline.fields import FieldError
from pipeline.fields.rules import Float, Pair
from pipeline.render.command import RenderRequest
from pipeline.serve import view
from pipeline.serve.server import App, ServeOptions
from sky import AZIMUTH_TURN, ELEVATION_RANGE, TURBIDITY_RANGE, Light, SkyError

#: The page's controls of a number /api/view checks, by element id: the field each sends.
PAGE_CONTROLS = {
    "azimuth": "azimuth_deg",
    "elevation": "elevation_deg",
    "turbidity": "turbidity",
    "exposure": "exposure",
    "specular": "specular",
    "roughness": "roughness",
    "tilt": "tilt_deg",
    "seed": "seed",
}


class _Inputs(HTMLParser):
    def __init__(self):
        super().__init__()
        self.inputs: dict[str, dict] = {}

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "input" and "id" in attrs:
            self.inputs[attrs["id"]] = attrs


def _page_inputs() -> dict[str, dict]:
    parser = _Inputs()
    parser.feed(resources.files("pipeline.serve").joinpath("page.html").read_text())
    return parser.inputs


def _info() -> dict:
    return App(ServeOptions(port=0)).info()  # not started: no Mitsuba, no port


def test_the_pages_slider_ranges_come_from_api_info_and_are_the_domains():
    info, inputs = _info(), _page_inputs()
    for element, name in PAGE_CONTROLS.items():
        attrs = inputs[element]
        assert attrs.get("data-field") == name, (element, attrs)
        assert not {"min", "max", "value"} & set(attrs), f"page.html repeats a range or default: {element} {attrs}"
        assert name in info["ranges"] and name in info["defaults"]
    page = resources.files("pipeline.serve").joinpath("page.html").read_text()
    assert "info.ranges[name]" in page and "info.defaults[name]" in page
    ranges = {k: tuple(v) for k, v in info["ranges"].items()}
    assert ranges["elevation_deg"] == ELEVATION_RANGE
    assert ranges["azimuth_deg"] == AZIMUTH_TURN
    assert ranges["turbidity"] == TURBIDITY_RANGE
    assert ranges["specular"] == ALBEDO_RANGE
    assert ranges["roughness"] == ROUGHNESS_RANGE
    assert ranges["tilt_deg"] == view.TILT_RANGE and ranges["exposure"] == view.EXPOSURE_RANGE
    assert ranges["seed"] == view.SEED_RANGE
    assert info["defaults"]["azimuth_deg"] == 270.0 and info["defaults"]["exposure"] == 4.0


def test_api_info_ranges_are_what_the_api_checks():
    """Each range's ends are accepted and a step past either end is refused, by the API itself."""
    base = {"client": "x", "material": {"kind": "uniform"}, "light": {}}
    where = {"elevation_deg": "light", "azimuth_deg": "light", "turbidity": "light"}
    where.update(specular="material", roughness="material", tilt_deg="material")
    for name, (lo, hi) in _info()["ranges"].items():
        if name == "seed":
            continue  # an SVBRDF's (its family is needed): an Int rule of the same declaration
        for value, ok in ((lo, True), (hi, True), (lo - 1e-6, False), (hi * 1.001 + 1e-6, False)):
            doc = {**base, "material": dict(base["material"]), "light": {}}
            if name == "exposure":
                doc["exposure"] = value
            else:
                doc[where[name]][name] = value
            if ok:
                view.parse_view(doc)
            else:
                with pytest.raises(FieldError) as refused:
                    view.parse_view(doc)
                assert refused.value.name == name


def test_spec_render_serve_and_sky_refuse_an_elevation_with_the_same_words(tmp_path):
    """95 degrees: each surface names its own field, and what is allowed is built from
    sky.ELEVATION_RANGE in the one wording (a single sun: a number; the spec: a pair of them)."""
    number, pair = Float(*ELEVATION_RANGE).allowed, Pair(*ELEVATION_RANGE).allowed
    assert number == "a finite number from 0 to 90"

    with pytest.raises(FieldError) as render:
        RenderRequest(sun_sky={"elevation": 95.0}, out=str(tmp_path / "x.exr"))
    assert (render.value.name, render.value.allowed) == ("elevation", number)
    assert str(render.value) == f"elevation: 95.0 is not allowed; {number}"

    doc = {"client": "x", "material": {"kind": "uniform"}, "light": {"elevation_deg": 95.0}}
    with pytest.raises(FieldError) as served:
        view.parse_view(doc)
    assert (served.value.name, served.value.allowed) == ("elevation_deg", number)
    assert str(view.api_error(served.value)) == f"light.elevation_deg: 95.0 is not allowed; {number}"

    with pytest.raises(SkyError) as domain:
        Light(95.0, 0.0, 3.0)
    assert str(domain.value) == f"light.elevation_deg: 95.0 is not allowed; {number}"

    spec = '[dataset]\nname = "x"\nseed = 1\nmaterials = 1\n[lighting]\nelevation_deg = [10.0, 95.0]\n'
    with pytest.raises(SpecError) as specced:
        parse_spec_text(spec)
    assert specced.value.allowed == pair and pair.endswith("0 <= lo <= hi <= 90")
    assert "lighting.elevation_deg: [10.0, 95.0] is not allowed; " + pair in str(specced.value)
