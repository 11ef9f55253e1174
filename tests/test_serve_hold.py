"""`shaderball serve` holds: malformed requests, headers sent twice, HEAD, bursts, crowds of
tabs, other sites' requests, worst-case uploads. A real server (in-process, path tracing only, no
network) over real sockets; the memory check runs `shaderball serve` as a process of its own
(Ctrl-C: tests/test_serve_stop.py)."""

from __future__ import annotations

import io
import json
import os
import signal
import socket
import threading
import time
import zlib
from http.client import HTTPConnection
from pathlib import Path
from struct import pack

import numpy as np
import pytest

from pipeline.serve import server as server_module
from pipeline.serve import transport
from pipeline.serve.transport import HostPolicy
from pipeline.serve.view import UniformChoice, View
from pipeline.serve.workers import ABANDONED_S, IDLE_S, MAX_CLIENTS, Hub
from pipeline.store.exr import encode_exr
from sky import Light
from support.serving import in_threads, serve_process, start_app

REPO = Path(__file__).resolve().parents[1]
VIEW_DOC = {
    "material": {"kind": "uniform"},
    "light": {"azimuth_deg": 100.0, "elevation_deg": 40.0, "turbidity": 3.0},
    "exposure": 4.0,
}


@pytest.fixture(scope="module")
def app():
    """An app with neither dataset nor network (conftest's ``http`` talks to it)."""
    app = start_app(None, None)
    yield app
    app.close()


def _raw(http, data: bytes, shut: bool = False, timeout_s: float = 60.0) -> tuple[int, bytes, bytes]:
    """(status, head, body) of the reply to the bytes ``data`` sent on a fresh connection;
    ``shut``: the client closes its side once sent (a body cut short). Reads to the server's close."""
    with socket.create_connection((http.host, http.port), timeout=timeout_s) as sock:
        sock.sendall(data)
        if shut:
            sock.shutdown(socket.SHUT_WR)
        reply = b""
        while chunk := sock.recv(65536):
            reply += chunk
    head, _, body = reply.partition(b"\r\n\r\n")
    return int(head.split(b" ", 2)[1]), head, body


def _request(http, method: str, path: str, headers: dict[str, str], body: bytes = b"") -> bytes:
    host = {"Host": f"127.0.0.1:{http.port}"}
    lines = [f"{method} {path} HTTP/1.1"] + [f"{k}: {v}" for k, v in {**host, **headers}.items()]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("utf-8") + body


def _view_body(client: str, light: bytes | None = None) -> bytes:
    if light is None:
        return json.dumps({"client": client, **VIEW_DOC}).encode()
    return b'{"client": "' + client.encode() + b'", "material": {"kind": "uniform"}, "light": {' + light + b"}}"


JSON = {"Content-Type": "application/json", "Connection": "close"}
BATTERY = [
    # (what, method, path, headers, body, status, words in the error)
    ("length-superscript", "POST", "/api/view", {**JSON, "Content-Length": "²"}, b"", 400, "Content-Length"),
    ("length-float", "POST", "/api/view", {**JSON, "Content-Length": "1e3"}, b"", 400, "Content-Length"),
    ("length-negative", "POST", "/api/view", {**JSON, "Content-Length": "-1"}, b"", 400, "Content-Length"),
    ("length-huge", "POST", "/api/view", {**JSON, "Content-Length": "9" * 40}, b"", 400, "Content-Length"),
    ("length-past-limit", "POST", "/api/view", {**JSON, "Content-Length": "9" * 15}, b"", 413, "body"),
    ("chunked", "POST", "/api/view", {**JSON, "Transfer-Encoding": "chunked"}, b"0\r\n\r\n", 411, "Content-Length"),
    ("since-superscript", "GET", "/api/frame?client=a&since=%C2%B2", {"Connection": "close"}, b"", 400, "since"),
    ("since-float", "GET", "/api/frame?client=a&since=1e3", {"Connection": "close"}, b"", 400, "since"),
    ("since-huge", "GET", "/api/frame?client=a&since=" + "9" * 40, {"Connection": "close"}, b"", 400, "since"),
    ("azimuth-inf", "POST", "/api/view", JSON, _view_body("n", b'"azimuth_deg": 1e400'), 400, "light.azimuth_deg"),
    ("azimuth-huge-int", "POST", "/api/view", JSON, _view_body("n", b'"azimuth_deg": 1' + b"0" * 400), 400, "light"),
    ("no-host", "GET", "/api/info", {"Host": "", "Connection": "close"}, b"", 421, "Host"),
    ("foreign-host", "GET", "/api/info", {"Host": "evil.example", "Connection": "close"}, b"", 421, "Host"),
    ("text-plain", "POST", "/api/view", {"Content-Type": "text/plain", "Connection": "close"}, b"{}", 415, "Type"),
]


@pytest.mark.parametrize("what, method, path, headers, body, status, words", BATTERY, ids=[b[0] for b in BATTERY])
def test_malformed_requests_are_a_4xx_naming_what_never_a_5xx(http, what, method, path, headers, body, status, words):
    if body and "Content-Length" not in headers and "Transfer-Encoding" not in headers:
        headers = {**headers, "Content-Length": str(len(body))}
    got, head, reply = _raw(http, _request(http, method, path, headers, body))
    assert got == status, (head, reply[:300])
    doc = json.loads(reply)
    assert doc["ok"] is False and words in doc["error"] and "internal" not in doc["error"], doc


def test_a_body_cut_short_by_its_client_is_a_4xx(http):
    head = _request(http, "POST", "/api/view", {**JSON, "Content-Length": "500"}, b'{"client": ')
    status, _, body = _raw(http, head, shut=True)
    assert status == 400 and "11 of its 500 bytes" in json.loads(body)["error"]


def test_a_stalled_body_is_408_and_closed_not_a_500(http, monkeypatch):
    monkeypatch.setattr(transport, "BODY_STALL_S", 0.5)  # the figure, lowered for the test's time
    status, _, body = _raw(http, _request(http, "POST", "/api/view", {**JSON, "Content-Length": "500"}, b'{"c'))
    assert status == 408 and "3 of its 500 bytes" in json.loads(body)["error"]


@pytest.mark.parametrize(
    "path", ["/", "/api/info", "/api/frame?client=headless&since=0", "/api/view", "/nowhere", "/api/frame?since=x"]
)
def test_head_answers_wherever_get_does_with_its_headers_and_never_a_body(http, app, path):
    status, head, body = _raw(http, _request(http, "HEAD", path, {"Connection": "close"}))
    get_status, get_head, get_body = _raw(http, _request(http, "GET", path, {"Connection": "close"}))
    assert (status, body) == (get_status, b""), (head, body[:100])
    assert _header(head, "Content-Type") == _header(get_head, "Content-Type")
    assert int(_header(head, "Content-Length")) == len(get_body) > 0
    assert not app.hub.knows("headless")  # a HEAD, as a GET, makes no client


def _header(head: bytes, name: str) -> str:
    lines = head.decode("latin-1").split("\r\n")[1:]
    (value,) = [line.split(":", 1)[1].strip() for line in lines if line.lower().startswith(name.lower() + ":")]
    return value


@pytest.mark.parametrize(
    "path, first, second",
    [
        ("/api/info", "Host: 127.0.0.1:{port}", "Host: evil.example"),
        ("/", "Host: 127.0.0.1:{port}", "Host: 127.0.0.1:{port}"),
        ("/api/info", "Host: evil.example", "Host: 127.0.0.1:{port}"),
        ("/api/view", "Content-Length: 2", "Content-Length: 40"),
        ("/api/view", "Content-Type: application/json", "Content-Type: text/plain"),
        ("/api/frame?client=a", "Origin: http://127.0.0.1:{port}", "Origin: http://evil.example"),
    ],
)
def test_a_header_sent_twice_is_400_even_with_a_good_one_first(http, path, first, second):
    name = first.split(":")[0]
    method = "POST" if path == "/api/view" else "GET"
    lines = [f"{method} {path} HTTP/1.1", first, second, "Connection: close"]
    if name != "Host":
        lines.append(f"Host: 127.0.0.1:{http.port}")
    if method == "POST" and name != "Content-Length":
        lines.append("Content-Length: 2")
    if method == "POST" and name != "Content-Type":
        lines.append("Content-Type: application/json")
    data = ("\r\n".join(lines) + "\r\n\r\n").format(port=http.port).encode() + (b"{}" if method == "POST" else b"")
    status, head, body = _raw(http, data)
    assert status == 400 and f"{name}: sent 2 times" in json.loads(body)["error"], (head, body)


def test_a_burst_of_64_connections_is_queued_and_answered_without_a_reset(app):
    """64 connections arrive while the server accepts none (as when its accept loop is busy):
    the listen queue holds them all, each handshake completes at once, and once the server runs
    each gets its answer (half GET /api/info, half a view of 32 tabs). With ThreadingHTTPServer's
    queue of 5, connections past it are dropped by the kernel (reset, or a connect that hangs)."""
    srv = server_module.QuietServer(("127.0.0.1", 0), server_module.handler_for(app))
    port = srv.server_address[1]
    host = {"Host": f"127.0.0.1:{port}", "Connection": "close"}

    def request(i: int) -> bytes:
        if i % 2:
            return _request_to(host, "GET", "/api/info", {})
        body = _view_body(f"burst{i}")
        return _request_to(host, "POST", "/api/view", {**JSON, "Content-Length": str(len(body))}, body)

    socks, errors = [None] * 64, []

    def connect(i: int) -> None:
        try:
            socks[i] = socket.create_connection(("127.0.0.1", port), timeout=5)  # a dropped SYN waits 1 s, 3 s...
            socks[i].sendall(request(i))
        except OSError as exc:
            errors.append(exc)

    in_threads(64, connect, 60)
    serving = threading.Thread(target=srv.serve_forever, daemon=True)
    serving.start()
    try:
        statuses = [_reply(sock) for sock in socks if sock is not None]
    finally:
        srv.shutdown()
        srv.server_close()
        for sock in socks:
            if sock is not None:
                sock.close()
    assert errors == [] and statuses == [200] * 64, (errors[:3], statuses)


def _request_to(host: dict, method: str, path: str, headers: dict, body: bytes = b"") -> bytes:
    lines = [f"{method} {path} HTTP/1.1"] + [f"{k}: {v}" for k, v in {**host, **headers}.items()]
    return ("\r\n".join(lines) + "\r\n\r\n").encode() + body


def _reply(sock) -> int | OSError:
    try:
        sock.settimeout(60)
        reply = b""
        while chunk := sock.recv(65536):
            reply += chunk
        return int(reply.split(b" ", 2)[1])
    except (OSError, IndexError) as exc:
        return exc


# --------------------------------------------------------------------------- Host, Origin, type


@pytest.mark.parametrize("host", ["127.0.0.1:{port}", "localhost:{port}", "LOCALHOST:{port}", "[::1]:{port}"])
def test_the_served_address_and_localhost_are_allowed(http, host):
    status, _, _ = _raw(
        http, _request(http, "GET", "/api/info", {"Host": host.format(port=http.port), "Connection": "close"})
    )
    assert status == 200


@pytest.mark.parametrize("host", ["evil.example:{port}", "127.0.0.1:1", "127.0.0.1", "rebind.127.0.0.1.nip.io:{port}"])
def test_a_foreign_host_is_refused(http, host):
    status, _, body = _raw(
        http, _request(http, "GET", "/", {"Host": host.format(port=http.port), "Connection": "close"})
    )
    assert status == 421 and "Host: " in json.loads(body)["error"]


@pytest.mark.parametrize(
    "method, path, headers",
    [
        ("GET", "/api/frame?client=g1&since=0", {"Sec-Fetch-Site": "cross-site"}),  # another site's <img>
        ("GET", "/api/frame?client=g2&since=0", {"Sec-Fetch-Site": "same-site"}),  # another port of this host
        ("GET", "/api/frame?client=g3&since=0", {"Origin": "http://evil.example"}),
        ("GET", "/api/info", {"Sec-Fetch-Site": "cross-site"}),
        ("POST", "/api/view", {"Sec-Fetch-Site": "cross-site", **JSON}),
        ("POST", "/api/upload?client=g4&map=diffuse", {"Sec-Fetch-Site": "same-site", "Content-Type": "image/png"}),
    ],
)
def test_another_sites_request_to_the_api_is_refused_and_makes_no_client(http, app, method, path, headers):
    body = _view_body("g5") if path == "/api/view" else (_png(8, 8) if method == "POST" else b"")
    headers = {"Connection": "close", **headers, **({"Content-Length": str(len(body))} if body else {})}
    status, _, reply = _raw(http, _request(http, method, path, headers, body))
    assert status == 403 and ("Sec-Fetch-Site" in headers) == ("Sec-Fetch-Site" in json.loads(reply)["error"])
    assert not any(app.hub.knows(f"g{i}") for i in range(1, 6))


def test_the_page_itself_may_be_linked_from_anywhere_and_its_own_requests_are_served(http):
    for site in ("cross-site", "none"):
        assert _raw(http, _request(http, "GET", "/", {"Sec-Fetch-Site": site, "Connection": "close"}))[0] == 200
    own = {"Sec-Fetch-Site": "same-origin", "Connection": "close"}
    assert _raw(http, _request(http, "GET", "/api/info", own))[0] == 200
    body = _view_body("own-page")
    view = {**own, **JSON, "Content-Length": str(len(body)), "Origin": f"http://127.0.0.1:{http.port}"}
    assert _raw(http, _request(http, "POST", "/api/view", view, body))[0] == 200


def test_a_frame_poll_never_makes_a_client_a_post_does(http, app):
    status, frame = http.json("GET", "/api/frame?client=ghost&since=0")  # no browser headers at all
    assert status == 200 and frame == {"version": 0, "known": False} and not app.hub.knows("ghost")
    assert http.view("ghost")[0] == 200 and app.hub.knows("ghost")


def test_a_cross_origin_post_is_refused_and_a_same_origin_one_served(http):
    body = _view_body("origin")
    base = {**JSON, "Content-Length": str(len(body))}
    foreign = _raw(http, _request(http, "POST", "/api/view", {**base, "Origin": "http://evil.example"}, body))
    assert foreign[0] == 403 and "Origin" in json.loads(foreign[2])["error"]
    null = _raw(http, _request(http, "POST", "/api/view", {**base, "Origin": "null"}, body))
    assert null[0] == 403
    own = _raw(http, _request(http, "POST", "/api/view", {**base, "Origin": f"http://127.0.0.1:{http.port}"}, body))
    assert own[0] == 200, own
    plain = {**base, "Content-Type": "text/plain", "Origin": "http://evil.example"}  # a cross-site form's
    assert _raw(http, _request(http, "POST", "/api/view", plain, body))[0] in (403, 415)


def _png(width: int, height: int) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.new("RGB", (width, height), (200, 100, 50)).save(buffer, format="PNG")
    return buffer.getvalue()


@pytest.mark.parametrize(
    "kind, status", [("image/png", 200), ("application/octet-stream", 200), ("application/json", 415), (None, 415)]
)
def test_an_upload_needs_an_image_type(http, kind, status):
    headers = {"Connection": "close", "Content-Length": str(len(png := _png(8, 8)))}
    if kind:
        headers["Content-Type"] = kind
    got, _, body = _raw(http, _request(http, "POST", "/api/upload?client=types&map=diffuse", headers, png))
    assert got == status, body


def test_every_address_bound_allows_ip_literals_and_this_machines_names_not_other_names():
    policy = HostPolicy.of("0.0.0.0", 8765)
    assert policy.allows("192.168.1.7:8765") and policy.allows("[fe80::1]:8765")
    assert policy.allows(f"{socket.gethostname()}:8765") and policy.allows("localhost:8765")
    assert not policy.allows("evil.example:8765") and not policy.allows("192.168.1.7:80")
    assert not HostPolicy.of("127.0.0.1", 8765).allows("192.168.1.7:8765")


# --------------------------------------------------------------------------- a client's life

VIEW = View(UniformChoice((0.5, 0.5, 0.5), 0.04, 0.3, False, 0.0), Light(45.0, 270.0, 3.0), 4.0)


class Clock:
    def __init__(self):
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_when_full_the_client_idle_longest_gives_way_and_a_frame_poll_makes_none():
    clock = Clock()
    hub = Hub(path_resolution=16, network_resolution=None, clock=clock)
    hub.store_upload("first", "diffuse", np.zeros((4, 4, 3), np.float32))  # a POST makes a client
    for i in range(MAX_CLIENTS - 1):
        clock.now += 1
        hub.uploads(f"tab{i}")  # what a view's POST does first
    assert len(hub.clients) == MAX_CLIENTS
    assert hub.frame("poller", 0, 0.0) == {"version": 0, "known": False} and not hub.knows("poller")
    clock.now += 1
    hub.frame("first", 0, 0.0)  # an open tab polls: it is not the one idle longest
    hub.uploads("newcomer")  # a new tab: tab0, idle longest, gives way; never a 503
    assert hub.knows("newcomer") and hub.knows("first") and not hub.knows("tab0")
    assert len(hub.clients) == MAX_CLIENTS and "diffuse" in hub.uploads("first")
    clock.now += IDLE_S + 1
    hub.frame("first", 0, 0.0)
    hub.uploads("late")  # every client idle past IDLE_S is forgotten once room is needed
    assert set(hub.clients) == {"first", "late"}


def test_a_forgotten_client_is_told_so_at_once_and_a_held_one_is_not(http, app, monkeypatch):
    # A poll's wait far longer than the client's socket timeout (60 s): told at once, or the test fails.
    monkeypatch.setattr(server_module, "FRAME_WAIT_S", 3600.0)
    status, doc = http.view("told")
    assert status == 200 and doc["known"] is False and doc["uploads"] == []  # a new tab
    status, doc = http.view("told")
    assert doc["known"] is True
    status, frame = http.json("GET", "/api/frame?client=told&since=0")
    assert frame["known"] is True
    with app.hub.lock:
        app.hub.forget("told")  # as IDLE_S of silence, or a newer tab when full, would
    status, frame = http.json("GET", f"/api/frame?client=told&since={10**9}")
    assert status == 200 and frame == {"version": 0, "known": False}
    # Forgotten while its long poll waits: the poll answers then.
    assert http.view("told")[0] == 200
    answers = []
    poll = threading.Thread(target=lambda: answers.append(http.json("GET", f"/api/frame?client=told&since={10**9}")))
    poll.start()
    while poll.is_alive() and not _waiting_polls(app):
        time.sleep(0.01)
    with app.hub.lock:
        app.hub.forget("told")
    poll.join(120)
    assert answers == [(200, {"version": 0, "known": False})]


def _waiting_polls(app) -> int:
    return len(app.hub.lock._waiters)  # threading.Condition's own list: the long polls waiting


def test_an_abandoned_clients_job_is_parked_and_resumes_when_it_polls_again(http, app):
    offset = [0.0]
    app.hub.clock = lambda: time.monotonic() + offset[0]
    try:
        status, doc = http.view("leaver", azimuth=150.0)
        assert status == 200
        offset[0] = ABANDONED_S + 1  # no request for longer than ABANDONED_S: its tab is gone
        deadline = time.monotonic() + 120
        while "leaver" not in app.hub.parked and time.monotonic() < deadline:
            time.sleep(0.05)
        with app.hub.lock:
            assert "leaver" in app.hub.parked
            spp = app.hub.clients["leaver"].frame.get("path", {}).get("spp", 0)
        assert spp < 64 and all(job.client != "leaver" for job in app.hub.path_slots.jobs.values())
        frame = http.wait_frame("leaver", doc["generation"], lambda f: f.get("path", {}).get("spp") == 64)
        assert frame["known"] is True and "leaver" not in app.hub.parked
    finally:
        app.hub.clock = time.monotonic


# --------------------------------------------------------------------------- as a process


def _post(port: int, path: str, body: bytes, kind: str) -> int:
    conn = HTTPConnection("127.0.0.1", port, timeout=300)
    try:
        conn.request("POST", path, body=body, headers={"Content-Type": kind})
        response = conn.getresponse()
        response.read()
        return response.status
    finally:
        conn.close()


def png16_4096() -> bytes:
    """The worst upload the limits let through: 4096 x 4096 pixels of 16-bit RGB, 100 kB."""
    side = 4096

    def chunk(kind: bytes, data: bytes) -> bytes:
        return pack(">I", len(data)) + kind + data + pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    rows = (b"\0" + b"\x40\x00" * 3 * side) * side
    ihdr = pack(">IIBBBBB", side, side, 16, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(rows, 9)) + chunk(b"IEND", b"")


def _peak_rss_bytes(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise AssertionError("no VmHWM")


#: Peak resident memory allowed to the server under the worst uploads at once.
PEAK_RSS_BYTES = 1536 * 1024 * 1024


@pytest.mark.slow
def test_worst_case_uploads_at_once_stay_within_the_memory_bound():
    """16 tabs upload a 4096 x 4096 16-bit PNG at once, then 8 a 4096 x 4096 float EXR: the
    server's peak resident memory (VmHWM) stays under PEAK_RSS_BYTES and every upload lands."""
    png = png16_4096()
    exr = encode_exr({"diffuse": np.zeros((4096, 4096, 3), np.float32)})
    proc, port = serve_process()
    try:
        before = _peak_rss_bytes(proc.pid)
        pngs = in_threads(16, lambda i: _post(port, f"/api/upload?client=m{i}&map=diffuse", png, "image/png"))
        exrs = in_threads(8, lambda i: _post(port, f"/api/upload?client=e{i}&map=normal", exr, "image/x-exr"))
        peak = _peak_rss_bytes(proc.pid)
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        proc.communicate(timeout=120)
    print(f"peak RSS {peak / 2**20:.0f} MiB (at start {before / 2**20:.0f} MiB)")
    assert pngs == [200] * 16 and exrs == [200] * 8
    assert peak < PEAK_RSS_BYTES, f"peak RSS {peak / 2**20:.0f} MiB"
