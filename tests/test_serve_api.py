"""`shaderball serve` through real HTTP: a server started in-process on a free port, with the
smoke dataset and a tiny trained network. Views render (network, progressive path tracing,
difference); only the latest view of a client renders; every bad input gets a 4xx JSON error
that names what was wrong; clients that go away or crowd in do not break it."""

from __future__ import annotations

import io
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from pipeline.serve.materials import MAX_UPLOAD_BYTES, MAX_UPLOAD_PIXELS
from pipeline.store.exr import encode_exr
from support.serving import Client, in_threads, serve_process

torch.set_num_threads(1)
pytestmark = pytest.mark.slow  # a smoke build, a tiny training run and real renders
REPO = Path(__file__).resolve().parents[1]
FULL = {"path": lambda f: f.get("path", {}).get("spp") == 64}


def _png(width: int, height: int, colour=(200, 100, 50)) -> bytes:
    buffer = io.BytesIO()
    Image.new("RGB", (width, height), colour).save(buffer, format="PNG")
    return buffer.getvalue()


def _pixel_bomb_png(width: int, height: int) -> bytes:
    """A valid 1x1 PNG whose header claims width x height pixels (CRC fixed up)."""
    data = bytearray(_png(1, 1))
    ihdr = bytearray(data[12:29])  # b"IHDR" + 13 bytes
    ihdr[4:12] = struct.pack(">II", width, height)
    data[12:29] = ihdr
    data[29:33] = struct.pack(">I", zlib.crc32(bytes(ihdr)) & 0xFFFFFFFF)
    return bytes(data)


def test_the_page_is_served_whole_with_nothing_from_the_internet(http):
    status, kind, body = http.request("GET", "/")
    assert status == 200 and kind.startswith("text/html")
    text = body.decode()
    assert 'id="azimuth"' in text and 'id="net-img"' in text and 'id="path-img"' in text
    assert "http://" not in text and "https://" not in text and "<script src" not in text


def test_info_lists_the_network_and_exactly_the_manifests_samples(http, reference):
    status, info = http.json("GET", "/api/info")
    assert status == 200
    assert info["network"]["resolution"] == 64 and info["train_hint"] is None
    ids = [json.loads(line)["id"] for line in (reference / "manifest.jsonl").read_text().splitlines() if line]
    assert [s["id"] for s in info["samples"]] == ids
    assert info["passes_spp"] == [1, 4, 16, 64]


def test_a_sun_move_changes_the_network_and_the_path_traced_pictures(http):
    need = lambda f: "network" in f and f.get("path", {}).get("spp") == 64 and "diff" in f  # noqa: E731
    status, doc = http.view("move", azimuth=200.0)
    assert status == 200
    first = http.wait_frame("move", doc["generation"], need)
    status, doc = http.view("move", azimuth=20.0)
    second = http.wait_frame("move", doc["generation"], need)
    assert second["network"]["png"] != first["network"]["png"]
    assert second["path"]["png"] != first["path"]["png"]
    for frame in (first, second):
        assert frame["network"]["resolution"] == 64 and frame["path"]["resolution"] == 128
        assert frame["network"]["network_ms"] > 0 and frame["path"]["seconds"] > 0
        assert 0 < frame["path"]["noise_rel"] < 10
        assert 5 < frame["diff"]["psnr_db"] < 100 and 10 < frame["diff"]["noise_psnr_db"] < 100
        assert frame["maps"].startswith("data:image/png;base64,")


def test_only_the_latest_view_of_a_client_renders(http, app):
    generations = [http.view("drag", azimuth=float(a))[1]["generation"] for a in range(100, 160, 10)]
    assert generations == sorted(generations) and len(set(generations)) == len(generations)
    last = generations[-1]
    frame = http.wait_frame("drag", last, FULL["path"])
    assert frame["generation"] == last
    # Nothing of the older views is pending any more: the slots hold no job of this client.
    assert all(job.client != "drag" or job.generation == last for job in app.hub.path_slots.jobs.values())


def test_uploaded_maps_png_and_exr_render(http):
    status, doc = http.upload("up", "diffuse", _png(40, 30))
    assert status == 200 and doc["texels"] == [256, 256]
    rough = encode_exr({"roughness": np.full((16, 16, 1), 0.6, np.float32)})
    status, doc = http.upload("up", "roughness", rough, "image/x-exr")
    assert status == 200, doc
    status, doc = http.view("up", material={"kind": "maps"})
    frame = http.wait_frame("up", doc["generation"], lambda f: "path" in f)
    assert frame["path"]["spp"] >= 1


@pytest.mark.parametrize(
    "material",
    [
        {"kind": "svbrdf", "family": "tiles", "seed": 3},
        {"kind": "uniform", "diffuse": [0.9, 0.6, 0.2], "roughness": 0.2, "metal": True, "tilt_deg": 20},
    ],
    ids=["svbrdf", "metal-tilted"],
)
def test_every_material_control_renders(http, material):
    status, doc = http.view("materials", material=material)
    assert status == 200, doc
    frame = http.wait_frame("materials", doc["generation"], lambda f: "path" in f and "network" in f)
    assert frame["maps"].startswith("data:image/png;base64,")


def test_a_dataset_sample_is_picked_by_its_id(http, reference):
    sample = json.loads((reference / "manifest.jsonl").read_text().splitlines()[-1])["id"]
    status, doc = http.view("pick", material={"kind": "dataset", "sample": sample})
    assert status == 200, doc
    http.wait_frame("pick", doc["generation"], lambda f: "path" in f and "network" in f)


def _view(**change):
    doc = {
        "client": "bad",
        "material": {"kind": "uniform"},
        "light": {"azimuth_deg": 10.0, "elevation_deg": 30.0, "turbidity": 3.0},
        "exposure": 4.0,
    }
    for key, value in change.items():
        where, _, field = key.partition("__")
        if field:
            doc[where][field] = value
        else:
            doc[where] = value
    return doc


@pytest.mark.parametrize(
    "change, status, words",
    [
        ({"light__azimuth_deg": 400.0}, 400, "light.azimuth_deg: 400.0"),
        ({"light__elevation_deg": -5}, 400, "light.elevation_deg: -5"),
        ({"light__turbidity": 0.5}, 400, "light.turbidity: 0.5"),
        ({"light__turbidity": "3"}, 400, 'light.turbidity: "3"'),
        ({"exposure": 1e9}, 400, "exposure: 1000000000.0"),
        ({"material": {"kind": "uniform", "roughness": 2}}, 400, "material.roughness: 2"),
        ({"material": {"kind": "uniform", "diffuse": [1, 2]}}, 400, "material.diffuse"),
        ({"material": {"kind": "uniform", "tilt_deg": 89}}, 400, "material.tilt_deg: 89"),
        ({"material": {"kind": "svbrdf", "family": "lava"}}, 400, 'material.family: "lava"'),
        ({"material": {"kind": "svbrdf", "family": "tiles", "seed": -1}}, 400, "material.seed: -1"),
        ({"material": {"kind": "teapot"}}, 400, 'material.kind: "teapot"'),
        ({"material": {"kind": "dataset", "sample": "m999999_l0"}}, 404, 'material.sample: "m999999_l0"'),
        ({"material": {"kind": "dataset", "sample": "../../etc/passwd"}}, 400, 'material.sample: "../../etc/passwd"'),
        ({"material": {"kind": "dataset", "sample": "m000000_l0/../x"}}, 400, "material.sample"),
        ({"material": {"kind": "dataset", "sample": "/etc/passwd"}}, 400, 'material.sample: "/etc/passwd"'),
        ({"client": "../x"}, 400, 'client: "../x"'),
        ({"client": None}, 400, "client: none"),
        ({"light": 5}, 400, "light: 5 is not allowed; an object"),
    ],
)
def test_a_bad_view_is_refused_with_a_message_naming_it(http, change, status, words):
    got, doc = http.json("POST", "/api/view", _view(**change))
    assert (got, doc["ok"]) == (status, False)
    assert words in doc["error"] and "is not allowed; " in doc["error"]
    assert "Traceback" not in doc["error"]


@pytest.mark.parametrize(
    "raw, words",
    [
        (b'"azimuth_deg": 1e400', "light.azimuth_deg: inf is not allowed; a finite number from 0 to 360"),
        (b'"azimuth_deg": -1e400', "light.azimuth_deg: -inf is not allowed"),
        (b'"azimuth_deg": 1' + b"0" * 400, "light.azimuth_deg: 1000"),  # an int too large for a float
        (b'"azimuth_deg": "90"', 'light.azimuth_deg: "90" is not allowed'),
        (b'"azimuth_deg": true', "light.azimuth_deg: true is not allowed"),
        (b'"azimuth_deg": null', "light.azimuth_deg: none is not allowed"),
        (b'"azimuth_deg": [90]', "light.azimuth_deg: [90] is not allowed"),
        (b'"turbidity": NaN', "light.turbidity: nan is not allowed"),
    ],
    ids=["inf", "-inf", "huge-int", "string", "bool", "null", "list", "nan"],
)
def test_a_bad_number_is_a_4xx_naming_its_field_never_a_500(http, raw, words):
    """JSON numbers Python reads as inf, nan or an int past a float's range, and values that are
    no number: each refused as the field it is, 400, never an internal error."""
    body = b'{"client": "num", "material": {"kind": "uniform"}, "light": {' + raw + b"}}"
    status, doc = http.json("POST", "/api/view", raw=body)
    assert (status, doc["ok"]) == (400, False), doc
    assert doc["error"].startswith(words), doc["error"]


def test_a_huge_number_in_a_colour_is_refused_naming_it(http):
    body = b'{"client": "num", "material": {"kind": "uniform", "diffuse": [1' + b"0" * 400 + b', 0, 0]}, "light": {}}'
    status, doc = http.json("POST", "/api/view", raw=body)
    assert status == 400 and doc["error"].startswith("material.diffuse: [1000"), doc


@pytest.mark.parametrize(
    "raw, words",
    [
        (b"{not json", "body: not JSON"),
        (b"\xff\xfe", "body: not JSON"),
        (b"[1, 2]", "body: [1, 2]"),
        (b"[" * 60_000, "body: not JSON"),  # nested past the recursion limit
    ],
)
def test_malformed_json_is_refused(http, raw, words):
    status, doc = http.json("POST", "/api/view", raw=raw)
    assert status == 400 and words in doc["error"]


@pytest.mark.parametrize(
    "name, body, status, words",
    [
        ("diffuse", b"this is not an image at all", 415, "not a PNG or EXR"),
        ("diffuse", b"\x89PNG\r\n\x1a\n" + b"\0" * 64, 415, "not a readable PNG"),
        ("normal", _pixel_bomb_png(60_000, 60_000), 413, "60000x60000 pixels"),
        ("normal", _pixel_bomb_png(5_000, 5_000), 413, "5000x5000 pixels"),
        ("specular", b"\x76\x2f\x31\x01" + b"\0" * 64, 415, "not a readable EXR"),
        ("albedo", _png(4, 4), 404, 'map: "albedo" is not allowed'),
    ],
    ids=["text", "truncated-png", "png-bomb-pillow-bound", "png-bomb-our-bound", "truncated-exr", "unknown-map"],
)
def test_a_bad_upload_is_refused(http, name, body, status, words):
    got, doc = http.upload("bad", name, body, "application/octet-stream")
    assert (got, doc["ok"]) == (status, False) and words in doc["error"], doc


def _read_reply(sock) -> str:
    """The whole reply: the head and its body may arrive in separate reads."""
    data = b""
    while b"\r\n\r\n" not in data or len(data.partition(b"\r\n\r\n")[2]) < _content_length(data):
        chunk = sock.recv(65536)
        if not chunk:
            break
        data += chunk
    return data.decode("latin-1")


def _content_length(data: bytes) -> int:
    for line in data.partition(b"\r\n\r\n")[0].split(b"\r\n"):
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"content-length":
            return int(value)
    return 0


def test_an_oversized_upload_is_refused_unread(http):
    """The length is refused from the header: the answer comes before the body is sent."""
    with socket.create_connection((http.host, http.port), timeout=30) as sock:
        head = f"POST /api/upload?client=bad&map=diffuse HTTP/1.1\r\nHost: {http.host}:{http.port}\r\nContent-Type: image/png\r\nContent-Length: {MAX_UPLOAD_BYTES + 1}\r\n\r\n"
        sock.sendall(head.encode() + b"\0" * 1024)
        reply = _read_reply(sock)
    assert reply.startswith("HTTP/1.1 413")
    assert f"at most {MAX_UPLOAD_BYTES} bytes" in reply and "Traceback" not in reply
    assert MAX_UPLOAD_PIXELS < 5_000 * 5_000


def _exr_claiming(width: int, height: int) -> bytes:
    """A real 2x2 EXR whose header's dataWindow is patched to claim width x height pixels."""
    data = bytearray(encode_exr({"roughness": np.zeros((2, 2, 1), np.float32)}))
    key = b"dataWindow\0box2i\0" + struct.pack("<i", 16)
    at = data.index(key) + len(key)
    data[at : at + 16] = struct.pack("<iiii", 0, 0, width - 1, height - 1)
    return bytes(data)


def test_a_bomb_exr_is_refused_from_its_header(http):
    status, doc = http.upload("bad", "roughness", _exr_claiming(50_000, 50_000), "image/x-exr")
    assert status == 413 and "50000 x 50000 pixels" in doc["error"], doc


@pytest.mark.parametrize(
    "method, path, status",
    [
        ("GET", "/api/view", 405),
        ("GET", "/api/upload", 405),
        ("POST", "/api/info", 405),
        ("POST", "/", 405),
        ("PUT", "/api/view", 405),
        ("DELETE", "/", 405),
        ("GET", "/../../etc/passwd", 404),
        ("GET", "/page.html", 404),
        ("GET", "/api/frame?client=../x", 400),
        ("GET", "/api/frame?client=ok&since=-1", 400),
        ("GET", "/api/frame?" + "&".join(f"f{i}=1" for i in range(20)), 400),
        ("OPTIONS", "/api/view", 405),
    ],
)
def test_wrong_methods_and_paths_get_json_errors(http, method, path, status):
    got, doc = http.json(method, path, raw=b"{}" if method != "GET" else None)
    assert got == status and doc["ok"] is False and doc["error"]


def test_a_malformed_request_line_gets_a_json_error(http):
    with socket.create_connection((http.host, http.port), timeout=30) as sock:
        sock.sendall(b"GET / extra words HTTP/1.1\r\n\r\n")
        reply = _read_reply(sock)
    head, _, body = reply.partition("\r\n\r\n")
    assert head.startswith("HTTP/1.1 400") and "application/json" in head
    assert json.loads(body)["ok"] is False


def test_a_body_without_its_length_is_refused(http):
    with socket.create_connection((http.host, http.port), timeout=30) as sock:
        sock.sendall(
            f"POST /api/view HTTP/1.1\r\nHost: {http.host}:{http.port}\r\nContent-Type: application/json\r\n\r\n".encode()
        )
        reply = _read_reply(sock)
    assert reply.startswith("HTTP/1.1 411") and "Content-Length" in reply


def test_clients_that_go_away_and_clients_that_crowd_in_do_not_break_it(http):
    status, doc = http.view("gone", azimuth=90.0)
    for _ in range(5):  # ask for a frame and hang up before the answer
        with socket.create_connection((http.host, http.port), timeout=30) as sock:
            sock.sendall(
                f"GET /api/frame?client=gone&since=999999 HTTP/1.1\r\nHost: {http.host}:{http.port}\r\n\r\n".encode()
            )
        with socket.create_connection((http.host, http.port), timeout=30) as sock:
            sock.sendall(
                f"POST /api/view HTTP/1.1\r\nHost: {http.host}:{http.port}\r\nContent-Type: application/json\r\n"
                "Content-Length: 10\r\n\r\n{".encode()
            )
    results, errors = {}, []

    def one(i: int) -> None:
        try:
            name = f"crowd{i}"
            status, doc = http.view(name, azimuth=30.0 * i)
            assert status == 200, doc
            results[name] = http.wait_frame(name, doc["generation"], lambda f: "path" in f and "network" in f)
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    in_threads(6, one, 300)
    assert errors == [] and len(results) == 6
    status, _, _ = http.request("GET", "/")
    assert status == 200


def test_a_connection_reset_mid_request_prints_nothing(http, capfd):
    for _ in range(5):
        sock = socket.create_connection((http.host, http.port), timeout=30)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # close = reset
        sock.sendall(b"GET /api/fra")
        time.sleep(0.05)
        sock.close()
    status, _, _ = http.request("GET", "/")
    time.sleep(0.5)
    err = capfd.readouterr().err
    assert status == 200 and "Traceback" not in err and "Exception occurred" not in err, err


def _cli(*args, **kwargs):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run(
        [sys.executable, "-m", "cli", *args], cwd=REPO, env=env, capture_output=True, text=True, **kwargs
    )


@pytest.mark.parametrize(
    "args, words",
    [
        (["--port", "70000"], "--port: 70000"),
        (["--run", "/nonexistent/run"], "/nonexistent/run"),
        (["--dataset", "/nonexistent/data"], '--dataset: "/nonexistent/data" does not exist'),
        (["--dataset", "/"], '--dataset: "/" is no dataset folder'),
        (["--benchmark", "--repeats", "0"], "--repeats: 0"),
    ],
)
def test_bad_serve_options_exit_2_naming_them(args, words):
    result = _cli("serve", *args, timeout=300)
    assert result.returncode == 2, result.stderr
    assert words in result.stderr and "Traceback" not in result.stderr


def test_ctrl_c_stops_the_server_with_exit_code_130_and_one_line(tmp_path):
    proc, port = serve_process()
    try:
        client = Client(f"http://127.0.0.1:{port}/")
        status, doc = client.view("sigint")
        assert status == 200
        client.wait_frame("sigint", doc["generation"], lambda f: "path" in f)
        proc.send_signal(signal.SIGINT)  # most likely inside Mitsuba's render of the next chunk
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert out == "" and [line for line in err.splitlines() if line.strip()][-1].startswith(
        "stopped (Ctrl-C); served http://"
    )
    assert "Traceback" not in err


def test_a_dataset_sample_is_the_datasets_material_from_a_folder_or_its_publication(reference, tmp_path):
    """The picker makes a sample's material again from the spec and plan: the maps equal the
    texture maps the build stored (half floats), and a publication lists the same samples."""
    from click.testing import CliRunner

    from cli import main
    from pipeline.serve.materials import DatasetSamples
    from pipeline.serve.view import DatasetChoice
    from pipeline.store.exr import read_exr

    folder = DatasetSamples(str(reference))
    for line in (reference / "manifest.jsonl").read_text().splitlines()[::5]:
        record = json.loads(line)
        maps = folder.maps(DatasetChoice(record["id"]))
        texture = next(f["path"] for f in record["files"] if f["role"] == "texture")
        stored = read_exr(str(reference / texture)).layers
        for name in ("diffuse", "specular", "normal"):
            assert np.allclose(getattr(maps, name), stored[name], atol=2e-3), (record["id"], name)
        assert np.allclose(maps.roughness, stored["roughness"][..., 0], atol=2e-3)
    pub = tmp_path / "pub"
    result = CliRunner().invoke(main, ["publish", str(reference), "--out", str(pub)])
    assert result.exit_code == 0, result.output
    assert DatasetSamples(str(pub)).listing() == folder.listing()
