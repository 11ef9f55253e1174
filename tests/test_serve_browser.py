"""`shaderball serve` in a real headless Chromium, driven by Selenium (support.browser): the
pictures the page shows after a sun drag are those of the new view (the path-traced one
matches a direct `shaderball render` of it within its noise, the network's is what the live
network gives for it), exposure only re-tone-maps, a colour picked in sRGB is the ball's
colour, zoom and wipe show the pictures' pixels, an uploaded map is drawn on its canvas and
painting goes on over it, and a dataset sample shows its stored render.

Every wait is a WebDriverWait on a Python predicate that reads the page's own record of what
it shows: each picture's panel carries the generation of the view it belongs to
(``data-generation``), the path panel its spp, and #status the generation of the last view the
server accepted (``data-wanted``) and whether anything is still rendering (``data-busy``).

Debian's `chromium` and `chromium-driver` (`make chromium`, part of `make test`); without them
every test here is skipped with the reason. SHADERBALL_SERVE_RUN=RUN shows that run instead of
the tiny one trained here; SHADERBALL_SERVE_SCREENSHOT=FILE.png keeps the screenshot of the
finished view after the sun drag (docs/img/serve.png is one).
"""

from __future__ import annotations

import io
import json
import os
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from support.browser import WINDOW, data_url_pixels, start_browser, unavailable_reason
from support.serving import direct_render, start_app, train_tiny_run

torch.set_num_threads(1)
UNAVAILABLE = unavailable_reason()
pytestmark = [pytest.mark.slow, pytest.mark.skipif(UNAVAILABLE is not None, reason=UNAVAILABLE or "")]

#: Longest wait for a view to finish (64 spp at 128 px on 2 busy cores takes seconds).
VIEW_TIMEOUT_S = 240
#: Panels of the pictures, by the page's ids, that a finished view fills with a network.
WITH_NETWORK = ("net", "path", "diff")
#: Independent direct renders of one view: their spread measures the noise of a 64 spp frame.
NOISE_SEEDS = (101, 202)
#: A served frame may differ from a direct render by up to this many times the mean squared
#: difference of two direct renders (both are 64 spp estimates: their expected squared
#: difference is the same; the margin covers the 8-bit rounding and the spread of the estimate).
NOISE_MARGIN = 2.0


def _wait(driver, predicate, timeout_s: float = VIEW_TIMEOUT_S, message: str = ""):
    from selenium.webdriver.support.ui import WebDriverWait

    return WebDriverWait(driver, timeout_s, poll_frequency=0.2).until(lambda d: predicate(d), message)


def _by_id(driver, element_id: str):
    from selenium.webdriver.common.by import By

    return driver.find_element(By.ID, element_id)


def _settled(driver, after: int, panels=WITH_NETWORK):
    """The page's state once a view newer than generation ``after`` is finished and shown in
    every one of ``panels`` (else False): its generation, each picture's src and caption."""
    status = _by_id(driver, "status")
    if status.get_attribute("data-busy") != "false":
        return False
    wanted = int(status.get_attribute("data-wanted") or 0)
    if wanted <= after:
        return False
    state = {"generation": wanted, "status": status.text}
    for name in panels:
        panel = _by_id(driver, f"{name}-panel")
        if int(panel.get_attribute("data-generation") or 0) != wanted:
            return False
        state[name] = _by_id(driver, f"{name}-img").get_attribute("src")
        state[f"{name}-info"] = _by_id(driver, f"{name}-info").text
        state[f"{name}-spp"] = panel.get_attribute("data-spp")
    if state["path-spp"] != "64":
        return False
    state["error"] = _by_id(driver, "error").text
    return state


def _rendering_shown(driver) -> bool:
    status = _by_id(driver, "status")
    dimmed = all(
        "rendering" in _by_id(driver, f"{name}-panel").get_attribute("class")
        and float(_by_id(driver, f"{name}-img").value_of_css_property("opacity")) < 1
        for name in WITH_NETWORK
    )
    return dimmed and "rendering" in status.get_attribute("class") and status.text.startswith("rendering")


def _set(driver, element_id: str, value) -> None:
    """A control set as a user's input sets it: its value, then an input event."""
    driver.execute_script(
        "arguments[0].value = arguments[1]; arguments[0].dispatchEvent(new Event('input'));",
        _by_id(driver, element_id),
        value,
    )


def _slider_drag(driver, slider_id: str, to_fraction: float) -> None:
    """A mouse drag of the slider's thumb to ``to_fraction`` of its track."""
    from selenium.webdriver.common.action_chains import ActionChains

    slider = _by_id(driver, slider_id)
    driver.execute_script("arguments[0].scrollIntoView({block: 'center'});", slider)
    lo, hi, value = (float(slider.get_attribute(k)) for k in ("min", "max", "value"))
    width = slider.size["width"]
    start = -width / 2 + width * (value - lo) / (hi - lo)
    end = -width / 2 + width * to_fraction
    chain = ActionChains(driver).move_to_element_with_offset(slider, int(start), 0).click_and_hold()
    for step in range(1, 9):
        chain.move_to_element_with_offset(slider, int(start + (end - start) * step / 8), 0)
    chain.release().perform()


def _view_of_page(driver) -> dict:
    """The light and uniform material the page's controls say (the API's fields)."""
    from pipeline.image.srgb import srgb_decode

    value = lambda element_id: float(_by_id(driver, element_id).get_attribute("value"))  # noqa: E731
    swatch = _by_id(driver, "diffuse").get_attribute("value")
    srgb = np.array([int(swatch[i : i + 2], 16) for i in (1, 3, 5)], np.float64) / 255.0
    return {
        "light": {
            "azimuth_deg": value("azimuth"),
            "elevation_deg": value("elevation"),
            "turbidity": value("turbidity"),
        },
        "material": {
            "diffuse": srgb_decode(srgb).tolist(),
            "specular": value("specular"),
            "roughness": value("roughness"),
        },
        "exposure": 2.0 ** value("exposure"),
    }


def _mse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))


@pytest.fixture(scope="module")
def served(reference, tmp_path_factory):
    """One app with a network and the smoke dataset, and one browser on its page, for the module."""
    given = os.environ.get("SHADERBALL_SERVE_RUN")
    run = Path(given) if given else train_tiny_run(reference, tmp_path_factory.mktemp("serve") / "run")
    app = start_app(reference, run)
    driver = start_browser(str(tmp_path_factory.mktemp("chromium-profile")))
    try:
        driver.get(app.url)
        first = _wait(driver, lambda d: _settled(d, 0))
        yield {"app": app, "driver": driver, "run": run, "state": first, "tmp": tmp_path_factory.mktemp("renders")}
    finally:
        driver.quit()
        app.close()


def _current(served, kind: str | None = None) -> dict:
    """The finished state of the page's current view (waits while one is rendering), with
    the material of ``kind`` where given (the tests share the page; each sets what it needs)."""
    driver = served["driver"]
    if kind is not None and _by_id(driver, "kind").get_attribute("value") != kind:
        before = _wait(driver, lambda d: _settled(d, 0))
        _set(driver, "kind", kind)
        return _wait(driver, lambda d: _settled(d, before["generation"]))
    return _wait(driver, lambda d: _settled(d, 0))


def test_a_sun_drag_shows_the_new_views_pictures(served):
    driver, app, tmp = served["driver"], served["app"], served["tmp"]
    before = _current(served, "uniform")
    old_view = _view_of_page(driver)
    with app.hub.lock:  # the server takes no view and publishes nothing meanwhile: the page waits
        _slider_drag(driver, "azimuth", 0.12)
        new_view = _view_of_page(driver)
        # The old view's pictures stay up, marked as rendering: dimmed, the status says so.
        _wait(driver, _rendering_shown)
    assert new_view["light"]["azimuth_deg"] < 100, new_view
    after = _wait(driver, lambda d: _settled(d, before["generation"]))
    for name in ("net", "path", "diff"):
        assert after[name] != before[name], name
    assert "64 spp in" in after["path-info"] and "% rel. RMS" in after["path-info"], after["path-info"]
    assert "against this 64 spp frame" in after["diff-info"] and "~" in after["diff-info"], after["diff-info"]
    assert after["error"] == "" and after["status"].startswith("done: 64 spp")

    # The path-traced picture is a 64 spp estimate of the new view: as close to a direct render
    # of it as two direct renders are to each other, and not the old view's.
    shown = data_url_pixels(after["path"])
    resolution = shown.shape[0]
    render = lambda view, seed: direct_render(  # noqa: E731
        tmp / f"r{seed}.exr", view["light"], view["material"], resolution, 64, seed
    )
    to8 = lambda hdr: _srgb8(hdr, new_view["exposure"])  # noqa: E731
    first, second = (to8(render(new_view, seed)) for seed in NOISE_SEEDS)
    bound = NOISE_MARGIN * _mse(first, second)
    assert _mse(shown, first) <= bound, (_mse(shown, first), bound)
    stale = to8(render(old_view, NOISE_SEEDS[0]))
    assert _mse(shown, stale) > bound, "the old view's render would pass: the check cannot tell them apart"

    # The network's picture is exactly what the live network (infer's code path) gives for the
    # view the server holds, which is the page's.
    held = app.hub.clients[_client(driver)].view
    light = new_view["light"]
    assert (held.light.azimuth_deg, held.light.elevation_deg, held.light.turbidity) == (
        light["azimuth_deg"],
        light["elevation_deg"],
        light["turbidity"],
    )
    assert np.allclose(held.material.diffuse, new_view["material"]["diffuse"], atol=1e-9)
    assert np.array_equal(data_url_pixels(after["net"]), _network_picture(served, held))

    driver.execute_script("window.scrollTo(0, 0);")
    shot = driver.get_screenshot_as_png()
    assert Image.open(io.BytesIO(shot)).size == WINDOW
    keep = os.environ.get("SHADERBALL_SERVE_SCREENSHOT")
    if keep:
        Path(keep).write_bytes(shot)


def _srgb8(hdr: np.ndarray, exposure: float) -> np.ndarray:
    from pipeline.image.tonemap import hdr_to_srgb8

    return hdr_to_srgb8(hdr, exposure)


def _client(driver) -> str:
    return driver.find_element("tag name", "body").get_attribute("data-client")


def _network_picture(served, view) -> np.ndarray:
    """``view`` (the server's View) through a network loaded afresh from the run, as `infer`
    loads it, on the maps the server projects for its network (its G-buffer at the network's
    resolution)."""
    from pipeline.neural.live import LiveNetwork
    from pipeline.render.raster import project_material
    from pipeline.serve.materials import uniform_maps

    screen = project_material(uniform_maps(view.material), served["app"].tracer.network_gbuffer)
    hdr, _ = LiveNetwork(str(served["run"]), threads=1)(screen, view.light)
    return _srgb8(hdr, view.exposure)


def test_exposure_is_applied_without_rendering_again(served):
    driver = served["driver"]
    before = _current(served)
    exposure = float(_by_id(driver, "exposure").get_attribute("value")) - 1.0
    _set(driver, "exposure", str(exposure))
    shown = lambda d: float(_by_id(d, "path-panel").get_attribute("data-exposure") or "nan")  # noqa: E731
    _wait(driver, lambda d: shown(d) == 2.0**exposure)
    after = _wait(driver, lambda d: _settled(d, 0))
    # The same view (generation), still 64 spp, tone-mapped anew: darker, never a restart at 1 spp.
    assert after["generation"] == before["generation"]
    assert after["path-spp"] == "64" and after["path"] != before["path"]
    assert data_url_pixels(after["path"]).mean() < data_url_pixels(before["path"]).mean()


def test_a_colour_picked_in_srgb_is_the_balls_colour(served):
    driver, app = served["driver"], served["app"]
    before = _current(served, "uniform")
    _set(driver, "diffuse", "#b03020")
    _set(driver, "roughness", "0.5")  # a new view even where #b03020 is already picked
    _wait(driver, lambda d: _settled(d, before["generation"]))
    sent = app.hub.clients[_client(driver)].view.material.diffuse
    from pipeline.image.srgb import srgb_decode

    assert np.allclose(sent, srgb_decode(np.array([0xB0, 0x30, 0x20]) / 255.0), atol=1e-4), sent
    # The maps picture shows the diffuse albedo sRGB-encoded: on the ball it is the swatch.
    strip = data_url_pixels(_by_id(driver, "maps-img").get_attribute("src"))
    tile = strip[:, : strip.shape[1] // 4].reshape(-1, 3)
    ball = tile[tile.sum(axis=1) > 0]
    assert np.abs(np.median(ball, axis=0) - [0xB0, 0x30, 0x20]).max() <= 1, np.median(ball, axis=0)


def test_zoom_shows_pixels_and_the_wipe_shows_path_tracing_beside_the_network(served):
    driver = served["driver"]
    state = _current(served)
    _set(driver, "zoom", "4")
    path_img = _by_id(driver, "path-img")
    natural = driver.execute_script("return arguments[0].naturalWidth;", path_img)
    assert path_img.size["width"] == 4 * natural
    assert path_img.value_of_css_property("image-rendering") == "pixelated"
    frame = path_img.find_element("xpath", "..")
    assert driver.execute_script("return arguments[0].scrollWidth > arguments[0].clientWidth;", frame)
    # At 1x the wipe frame shows path tracing's pixels left of the wipe and the network's
    # (scaled up by whole pixels) right of it.
    _set(driver, "zoom", "1")
    _set(driver, "wipe", "30")
    wipe = _by_id(driver, "wipe-path").find_element("xpath", "..")
    driver.execute_script("arguments[0].scrollIntoView({block: 'center'});", wipe)
    seen = np.asarray(Image.open(io.BytesIO(wipe.screenshot_as_png)).convert("RGB"))
    path = data_url_pixels(state["path"])
    net = data_url_pixels(state["net"])
    side = path.shape[0]
    net_up = np.repeat(np.repeat(net, side // net.shape[0], axis=0), side // net.shape[1], axis=1)
    cut = int(side * 0.3)
    assert np.array_equal(seen[:side, : cut - 1], path[:, : cut - 1])
    assert np.array_equal(seen[:side, cut + 1 : side], net_up[:, cut + 1 :])
    _set(driver, "zoom", "2")


def test_an_upload_is_drawn_on_its_canvas_and_painting_paints_over_it(served, tmp_path):
    from selenium.webdriver.common.action_chains import ActionChains

    from pipeline.image.srgb import srgb_decode, srgb_encode

    driver, app = served["driver"], served["app"]
    _current(served)
    _set(driver, "kind", "maps")
    upload = np.array([51, 102, 153], np.uint8)  # an 8-bit albedo PNG: value / 255 is the linear albedo
    Image.new("RGB", (32, 32), tuple(int(v) for v in upload)).save(tmp_path / "diffuse.png")
    _by_id(driver, "up-diffuse").send_keys(str(tmp_path / "diffuse.png"))
    canvas = _by_id(driver, "cv-diffuse")
    _wait(driver, lambda d: canvas.get_attribute("data-drawn") == "1")
    texel = lambda x, y: driver.execute_script(  # noqa: E731
        "return Array.from(arguments[0].getContext('2d').getImageData(arguments[1], arguments[2], 1, 1).data);",
        canvas,
        x,
        y,
    )
    drawn = np.array(texel(20, 20)[:3])
    assert np.abs(drawn - np.round(srgb_encode(upload / 255.0) * 255)).max() <= 1, drawn
    # A dab of the brush in the middle: the canvas keeps the upload around it, and the map the
    # server holds has both (the brush's sRGB colour as a linear albedo).
    _set(driver, "brush", "#00ff40")
    driver.execute_script("arguments[0].scrollIntoView({block: 'center'});", canvas)
    ActionChains(driver).move_to_element(canvas).click_and_hold().release().perform()
    client = _client(driver)

    def painted(_):
        held = app.hub.uploads(client).get("diffuse")
        return held is not None and held[128, 128, 1] > 0.9 and [held]

    (held,) = _wait(driver, painted)
    side = held.shape[0]
    assert np.allclose(held[20, 20], upload / 255.0, atol=2 / 255), held[20, 20]
    assert np.allclose(held[side // 2, side // 2], srgb_decode(np.array([0, 255, 64]) / 255.0), atol=2 / 255)
    assert np.array_equal(texel(20, 20)[:3], drawn)
    assert _by_id(driver, "error").text == ""
    # The server forgets the tab (restarted, or it was idle too long): the page sends its
    # maps and its view again.
    with app.hub.lock:
        app.hub.clients.pop(client)
    _wait(driver, lambda d: _settled(d, 0))
    again = app.hub.uploads(client).get("diffuse")
    assert again is not None and np.array_equal(again, held)
    assert type(app.hub.clients[client].view.material).__name__ == "MapsChoice"


def test_a_dataset_sample_shows_its_stored_render(served, reference):
    from pipeline.store.exr import read_exr

    driver = served["driver"]
    before = _current(served)
    sample = json.loads((reference / "manifest.jsonl").read_text().splitlines()[0])
    _set(driver, "kind", "dataset")
    state = _wait(driver, lambda d: _settled(d, before["generation"], (*WITH_NETWORK, "ref")))
    assert sample["id"] in state["ref-info"] and "not the view's light" not in state["ref-info"], state["ref-info"]
    render_path = next(f["path"] for f in sample["files"] if f["role"] == "render")
    stored = read_exr(str(reference / render_path)).layers["render"][..., :3]
    exposure = 2.0 ** float(_by_id(driver, "exposure").get_attribute("value"))
    assert np.array_equal(data_url_pixels(state["ref"]), _srgb8(stored, exposure))


def test_without_a_network_the_page_is_a_path_traced_previewer(tmp_path):
    app = start_app(None, None)
    driver = start_browser(str(tmp_path / "chromium-profile"))
    try:
        driver.get(app.url)
        state = _wait(driver, lambda d: _settled(d, 0, ("path",)))
        assert "make serve-network" in _by_id(driver, "hint").text and state["error"] == ""
        # The sliders' ranges and starting values are /api/info's (the domain's), none the page's own.
        info = app.info()
        for slider, name in (("azimuth", "azimuth_deg"), ("elevation", "elevation_deg"), ("turbidity", "turbidity")):
            got = [float(_by_id(driver, slider).get_attribute(k)) for k in ("min", "max", "value")]
            assert got == [*info["ranges"][name], info["defaults"][name]], (slider, got)
        for panel in ("net-panel", "diff-panel", "wipe-panel"):
            assert not _by_id(driver, panel).is_displayed()
    finally:
        driver.quit()
        app.close()
