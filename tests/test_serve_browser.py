"""`shaderball serve` in a real headless Chromium: the page loads, a mouse drag moves the sun
slider, and the network's and the path-traced pictures change, with their times shown; paint
on a map's canvas reaches the maps and the render.

Debian's `chromium` (`make chromium`, part of `make test`), driven over the DevTools protocol
(support.browser). Without it every test here is skipped with the reason. Set
SHADERBALL_SERVE_SCREENSHOT=FILE.png to keep the screenshot (docs/img/serve.png is one), and
SHADERBALL_SERVE_RUN=RUN to show that run instead of the tiny one trained here.
"""

from __future__ import annotations

import io
import json
import os
import re
import shutil
from pathlib import Path

import pytest
import torch
from PIL import Image

from support.browser import Browser, unavailable_reason
from support.serving import start_app, train_tiny_run

torch.set_num_threads(1)
UNAVAILABLE = unavailable_reason()
pytestmark = [pytest.mark.slow, pytest.mark.skipif(UNAVAILABLE is not None, reason=UNAVAILABLE or "")]

SRC = "document.getElementById('{}').getAttribute('src') || ''"
#: Pixels of the maps picture's diffuse tile (its first quarter) that are the brush's green.
GREEN_DIFFUSE_TEXELS = """(() => {
  const img = document.getElementById('maps-img');
  if (!img.complete || !img.naturalWidth) return 0;
  const c = document.createElement('canvas'); c.width = img.naturalWidth / 4; c.height = img.naturalHeight;
  const g = c.getContext('2d'); g.drawImage(img, 0, 0);
  const d = g.getImageData(0, 0, c.width, c.height).data;
  let n = 0;
  for (let i = 0; i < d.length; i += 4) if (d[i + 1] > 150 && d[i] < 80) n++;
  return n;
})()"""
TEXT = "document.getElementById('{}').textContent"


@pytest.fixture
def browser(tmp_path):
    browser = Browser(str(tmp_path / "chromium-profile"))
    yield browser
    browser.close()


def _slider_drag(browser: Browser, slider: str, to_fraction: float) -> None:
    box = json.loads(
        browser.evaluate(
            f"(() => {{ const s = document.getElementById('{slider}'); s.scrollIntoView(); "
            "const r = s.getBoundingClientRect(); "
            "return JSON.stringify({x: r.left, y: r.top + r.height / 2, w: r.width, "
            "v: (s.value - s.min) / (s.max - s.min)}); })()"
        )
    )
    browser.drag(box["x"] + box["w"] * box["v"], box["y"], box["x"] + box["w"] * to_fraction, box["y"])


def _views_ready(browser: Browser, old: dict | None = None) -> dict:
    """The pictures' sources and captions once path tracing reached 64 spp and the network
    and the difference are shown (and, given ``old``, every picture differs from it)."""
    condition = (
        f"{TEXT.format('path-info')}.includes(' 64 spp') && {TEXT.format('net-info')}.includes(' ms')"
        f" && {TEXT.format('diff-info')}.includes('PSNR')"
    )
    if old is not None:
        condition += "".join(f" && {SRC.format(k)} !== {json.dumps(old[k])}" for k in ("net-img", "path-img"))
    browser.wait_for(condition, timeout_s=300)
    state = {k: browser.evaluate(SRC.format(k)) for k in ("net-img", "path-img", "diff-img")}
    state.update({k: browser.evaluate(TEXT.format(k)) for k in ("net-info", "path-info", "diff-info", "error")})
    return state


def test_without_a_network_the_page_is_a_path_traced_previewer(browser):
    app = start_app(None, None)
    try:
        browser.navigate(app.url)
        browser.wait_for(f"{TEXT.format('path-info')}.includes(' spp in ')", timeout_s=300)
        assert "make serve-network" in browser.evaluate(TEXT.format("hint"))
        # The sliders' ranges and starting values are /api/info's (the domain's), none the page's own.
        info = app.info()
        for slider, name in (("azimuth", "azimuth_deg"), ("elevation", "elevation_deg"), ("turbidity", "turbidity")):
            got = browser.evaluate(
                f"(() => {{ const s = document.getElementById('{slider}'); "
                "return JSON.stringify([+s.min, +s.max, +s.value]); })()"
            )
            assert json.loads(got) == [*info["ranges"][name], info["defaults"][name]], (slider, got)
        assert browser.evaluate("document.getElementById('net-img').parentElement.hidden") is True
        before = browser.evaluate(SRC.format("path-img"))
        _slider_drag(browser, "elevation", 0.2)
        browser.wait_for(f"{SRC.format('path-img')} !== {json.dumps(before)}", timeout_s=300)
        assert browser.evaluate(TEXT.format("error")) == ""
        # Paint on the diffuse canvas: the page uploads it and the maps and the render follow.
        browser.evaluate(
            "(() => { const k = document.getElementById('kind'); k.value = 'maps'; "
            "k.dispatchEvent(new Event('input')); document.getElementById('brush').value = '#00ff40'; })()"
        )
        browser.wait_for("!document.getElementById('maps-box').hidden")
        maps, path = browser.evaluate(SRC.format("maps-img")), browser.evaluate(SRC.format("path-img"))
        box = json.loads(
            browser.evaluate(
                "(() => { const c = document.getElementById('cv-diffuse'); c.scrollIntoView(); "
                "const r = c.getBoundingClientRect(); return JSON.stringify({x: r.left, y: r.top, w: r.width}); })()"
            )
        )
        for row in (0.2, 0.5, 0.8):
            y = box["y"] + box["w"] * row
            browser.drag(box["x"] + 2, y, box["x"] + box["w"] - 2, y)
        browser.wait_for(
            f"{SRC.format('maps-img')} !== {json.dumps(maps)} && {SRC.format('path-img')} !== {json.dumps(path)}",
            timeout_s=300,
        )
        browser.wait_for(GREEN_DIFFUSE_TEXELS, timeout_s=300)  # the paint, not just another material
        assert browser.evaluate(TEXT.format("error")) == ""
    finally:
        app.close()


def test_a_sun_drag_changes_the_network_and_the_path_traced_pictures(browser, reference, tmp_path):
    given = os.environ.get("SHADERBALL_SERVE_RUN")
    run = Path(given) if given else train_tiny_run(reference, tmp_path / "run")
    app = start_app(reference, run)
    try:
        browser.navigate(app.url)
        first = _views_ready(browser)
        assert browser.evaluate("document.getElementById('azimuth').value") == "270"
        _slider_drag(browser, "azimuth", 0.12)
        azimuth = float(browser.evaluate("document.getElementById('azimuth').value"))
        assert azimuth < 100, azimuth
        second = _views_ready(browser, first)
        for state in (first, second):
            assert re.search(r"network \d+(\.\d+)? ms", state["net-info"]), state["net-info"]
            assert re.search(r"64 spp in \d+(\.\d+)? s", state["path-info"]), state["path-info"]
            assert re.search(r"PSNR \d+(\.\d+)? dB", state["diff-info"]), state["diff-info"]
            assert state["error"] == ""
        assert second["diff-img"].startswith("data:image/png;base64,")
        browser.evaluate("window.scrollTo(0, 0)")
        shot = browser.screenshot()
        picture = Image.open(io.BytesIO(shot))
        assert picture.size == (1000, 900)
        keep = os.environ.get("SHADERBALL_SERVE_SCREENSHOT")
        (tmp_path / "serve.png").write_bytes(shot)
        if keep:
            shutil.copyfile(tmp_path / "serve.png", keep)
    finally:
        app.close()
