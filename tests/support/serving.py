"""A `shaderball serve` app started in-process on a free port, with a tiny trained network."""

from __future__ import annotations

import http.client
import json
import os
import subprocess
import threading
import time
from pathlib import Path
from urllib.parse import urlsplit

from click.testing import CliRunner

from cli import main
from support.processes import REPO, cli, started

#: A network small enough to train in seconds on the smoke dataset (its pictures are poor).
TINY_TRAIN = ["--loss", "l1", "--resolution", "64", "--width", "0.25", "--batch-size", "4", "--epochs", "2"]


def train_tiny_run(dataset: Path, out: Path) -> Path:
    result = CliRunner().invoke(main, ["train", str(dataset), "--out", str(out), "--threads", "1", *TINY_TRAIN])
    assert result.exit_code == 0, result.output
    return out


def start_app(dataset: Path | None, run: Path | None):
    from pipeline.neural.live import LiveNetwork
    from pipeline.serve.server import App, ServeOptions

    network = LiveNetwork(str(run), threads=1) if run is not None else None
    from pipeline.neural.stored import stored_renders

    options = ServeOptions(port=0, dataset=str(dataset) if dataset else None)
    app = App(options, network, stored_renders if dataset else None).start()
    app.serve_in_thread()
    return app


class Client:
    """JSON requests to the app over real HTTP (one connection per request)."""

    def __init__(self, url: str):
        parts = urlsplit(url)
        self.host, self.port = parts.hostname, parts.port

    def request(self, method: str, path: str, body: bytes | None = None, headers: dict | None = None):
        conn = http.client.HTTPConnection(self.host, self.port, timeout=60)
        try:
            conn.request(method, path, body=body, headers=headers or {})
            response = conn.getresponse()
            data = response.read()
        finally:
            conn.close()
        return response.status, response.getheader("Content-Type"), data

    def json(self, method: str, path: str, doc=None, raw: bytes | None = None):
        body = raw if raw is not None else (json.dumps(doc).encode() if doc is not None else None)
        status, kind, data = self.request(method, path, body, {"Content-Type": "application/json"})
        assert kind == "application/json", (status, kind, data[:200])
        return status, json.loads(data)

    def upload(self, client: str, name: str, data: bytes, kind: str = "image/png"):
        """POST /api/upload of ``data`` with its type, as the page sends it: (status, JSON answer)."""
        status, answer_kind, body = self.request(
            "POST", f"/api/upload?client={client}&map={name}", data, {"Content-Type": kind}
        )
        assert answer_kind == "application/json", (status, answer_kind, body[:200])
        return status, json.loads(body)

    def view(self, client: str, azimuth: float = 270.0, material: dict | None = None, **light):
        doc = {
            "client": client,
            "material": material or {"kind": "uniform", "diffuse": [0.7, 0.3, 0.2], "roughness": 0.3},
            "light": {"azimuth_deg": azimuth, "elevation_deg": 40.0, "turbidity": 3.0, **light},
            "exposure": 4.0,
        }
        return self.json("POST", "/api/view", doc)

    def wait_frame(self, client: str, generation: int, need, timeout_s: float = 240.0) -> dict:
        """The client's frame of ``generation`` once ``need(frame)`` holds."""
        deadline, since = time.monotonic() + timeout_s, 0
        while time.monotonic() < deadline:
            status, frame = self.json("GET", f"/api/frame?client={client}&since={since}")
            assert status == 200, frame
            since = frame["version"]
            assert "error" not in frame, frame["error"]
            if frame.get("generation") == generation and need(frame):
                return frame
        raise AssertionError(f"no frame of generation {generation} within {timeout_s} s")


def serve_process(*args: str) -> tuple[subprocess.Popen, int]:
    """`shaderball serve --port 0 ARGS` as a process in a session of its own; (process, port)
    once it serves (its `serving` line read from its stderr)."""
    proc = started(cli("serve", "--port", "0", *args), env=dict(os.environ, PYTHONPATH=str(REPO)))
    line = proc.stderr.readline()
    assert line.startswith("serving http://127.0.0.1:"), line + proc.stderr.read()
    return proc, int(line.split()[1].rstrip("/").rsplit(":", 1)[1])


def in_threads(count: int, call, timeout_s: float = 600) -> list:
    """``call(i)`` for each i below ``count``, all at once, a thread each, each waited for at
    most ``timeout_s``; what each returned (None where one had not)."""
    results = [None] * count
    threads = [threading.Thread(target=lambda i=i: results.__setitem__(i, call(i))) for i in range(count)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout_s)
    return results


def direct_render(out: Path, light: dict, material: dict, resolution: int, spp: int, seed: int):
    """`shaderball render` of a uniform ``material`` (the API's fields: linear diffuse, grey
    specular, roughness) under ``light`` (the API's fields), in its own process (Mitsuba's
    variant and state stay the server's): the linear HDR render (H, W, 3) float32."""
    import subprocess
    import sys

    from pipeline.store.exr import read_exr

    triple = lambda values: ",".join(repr(float(v)) for v in values)  # noqa: E731
    args = [
        str(Path(sys.executable).with_name("shaderball")),
        "render",
        "--out",
        str(out),
        "--resolution",
        str(resolution),
        "--spp",
        str(spp),
        "--seed",
        str(seed),
        "--variant",
        "llvm",
        "--diffuse",
        triple(material["diffuse"]),
        "--specular",
        triple([material["specular"]] * 3),
        "--roughness",
        repr(float(material["roughness"])),
        "--elevation",
        repr(float(light["elevation_deg"])),
        "--azimuth",
        repr(float(light["azimuth_deg"])),
        "--turbidity",
        repr(float(light["turbidity"])),
    ]
    done = subprocess.run(args, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, (args, done.stdout[-2000:], done.stderr[-2000:])
    return read_exr(str(out)).layers["render"][..., :3].astype("float32")
