"""`shaderball serve`'s tabs in a real headless Chromium (support.browser): a page of another site
with 64 ``<img>`` tags pointing at /api/frame takes none of the server's client slots, a tab
reloaded 64 times keeps its one client, and after each a new tab of the real page works.

The other site is a second HTTP server of this test on another host name and port
(``127.0.0.1:P2`` against the app's ``localhost:P``): to Chromium another site, so it sends what
it sends for another site's images (``Sec-Fetch-Site: cross-site``, no credentials asked).
"""

from __future__ import annotations

import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from pipeline.serve.transport import JsonHandler
from support.browser import start_browser, unavailable_reason
from support.serving import Client, start_app

UNAVAILABLE = unavailable_reason()
pytestmark = [pytest.mark.slow, pytest.mark.skipif(UNAVAILABLE is not None, reason=UNAVAILABLE or "")]

#: Longest wait for a page's view to finish (64 spp at 128 px on 2 busy cores takes seconds).
VIEW_TIMEOUT_S = 240
#: As many as the server holds clients: each would have taken a slot.
FOREIGN_IMAGES = 64
RELOADS = 64


@pytest.fixture(scope="module")
def app():
    app = start_app(None, None)
    yield app
    app.close()


@pytest.fixture(scope="module")
def driver(tmp_path_factory):
    driver = start_browser(str(tmp_path_factory.mktemp("chromium-profile")))
    yield driver
    driver.quit()


def _wait(driver, predicate, timeout_s: float = VIEW_TIMEOUT_S, message: str = ""):
    from selenium.webdriver.support.ui import WebDriverWait

    return WebDriverWait(driver, timeout_s, poll_frequency=0.1).until(lambda d: predicate(d), message)


def _page(driver) -> dict:
    """What the page says of itself: its client id, the generation of its last view the server
    accepted, whether it is still rendering, the path panel's spp, its error line."""
    return driver.execute_script(
        "const s = document.getElementById('status');"
        "return {client: document.body.dataset.client, wanted: +(s.dataset.wanted || 0), busy: s.dataset.busy,"
        " spp: document.getElementById('path-panel').dataset.spp || null,"
        " error: document.getElementById('error').textContent};"
    )


def _finished(driver):
    state = _page(driver)
    return state if state["wanted"] > 0 and state["busy"] == "false" and state["spp"] == "64" else False


def _new_tab_works(driver, url: str) -> dict:
    """A new tab of the real page finishes its first view, with no error."""
    driver.switch_to.new_window("tab")
    driver.get(url)
    state = _wait(driver, _finished, message="a new tab of the page never finished its view")
    assert state["error"] == "", state
    return state


class _OtherSite(BaseHTTPRequestHandler):
    page = b""

    def do_GET(self):  # noqa: N802 - http.server's name
        self.send_response(200)
        self.send_header("Content-Type", "text/html; charset=utf-8")
        self.send_header("Content-Length", str(len(self.page)))
        self.end_headers()
        self.wfile.write(self.page)

    def log_message(self, format, *args):  # noqa: A002 - the library's name
        pass


def test_another_sites_page_takes_no_client_and_a_new_tab_still_works(app, driver, monkeypatch):
    port = app.httpd.server_address[1]
    images = "".join(
        f'<img src="http://localhost:{port}/api/frame?client=g{i}&amp;since=0">' for i in range(FOREIGN_IMAGES)
    )
    handler = type("Page", (_OtherSite,), {"page": f"<!doctype html><body>{images}</body>".encode()})
    other = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=other.serve_forever, daemon=True).start()
    answered: list[tuple[str, object]] = []
    refusal = JsonHandler.refusal

    def recorded(self):
        got = refusal(self)
        if "client=g" in self.path:
            answered.append((self.path, got))
        return got

    monkeypatch.setattr(JsonHandler, "refusal", recorded)
    try:
        driver.get(f"http://127.0.0.1:{other.server_address[1]}/")
        _wait(driver, lambda d: d.execute_script("return Array.from(document.images).every((i) => i.complete);"))
    finally:
        other.shutdown()
        other.server_close()
    # Every image reached the server, and none took a client: each refused as another site's.
    assert len({path for path, _ in answered}) == FOREIGN_IMAGES, answered[:3]
    assert [app.hub.knows(f"g{i}") for i in range(FOREIGN_IMAGES)] == [False] * FOREIGN_IMAGES
    assert all(got is not None and got[0] == 403 and "Sec-Fetch-Site" in got[1] for _, got in answered), answered[:3]
    _new_tab_works(driver, f"http://localhost:{port}/")


def test_a_tab_reloaded_64_times_keeps_one_client_and_a_new_tab_still_works(app, driver):
    driver.get(app.url)
    first = _wait(driver, _finished)
    client, held_before = first["client"], set(app.hub.clients)
    # What the server holds for the tab (an upload) is not the reloaded page's: dropped on reload.
    status, _ = Client(app.url).upload(client, "diffuse", _png())
    assert status == 200 and "diffuse" in app.hub.clients[client].uploads
    for reload in range(RELOADS):
        before = _page(driver)["wanted"]
        driver.refresh()
        state = _wait(driver, lambda d, before=before: (s := _page(d))["wanted"] > 0 and s["wanted"] != before and s)
        assert state["client"] == client and state["error"] == "", (reload, state)
    assert set(app.hub.clients) == held_before, sorted(set(app.hub.clients) ^ held_before)
    assert app.hub.clients[client].uploads == {}
    assert _new_tab_works(driver, app.url)["client"] != client


def _png() -> bytes:
    import io

    from PIL import Image

    buffer = io.BytesIO()
    Image.new("RGB", (8, 8), (200, 100, 50)).save(buffer, format="PNG")
    return buffer.getvalue()
