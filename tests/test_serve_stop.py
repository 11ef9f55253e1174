"""Ctrl-C stops `shaderball serve` at any moment with one line and exit code 130: while the
`shaderball` script imports cli.py, while Mitsuba loads, idle, mid-render and mid-upload; and a
render under way is abandoned, not finished.

The processes are started as a user starts them: the console script, in a process group of its
own, SIGINT to the whole group (what a terminal's Ctrl-C does). Each moment is a fixed point
where one can be read (a native library mapped, /proc/PID/maps; a line printed; a request
answered), or a fraction of a calibration run's time to its `serving` line. Nothing here asserts
a time: each run's seconds from the signal to the process's end are printed
(``pytest -s tests/test_serve_stop.py``) for the figure docs/serve.md quotes.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from pipeline.ui.interrupt import INTERRUPTED_MESSAGE
from support.processes import has_mapped, started
from support.serving import Client

REPO = Path(__file__).resolve().parents[1]
SCRIPT = Path(sys.executable).with_name("shaderball")
#: The environment the `shaderball` script runs in: this checkout's code first.
SCRIPT_ENV = {**os.environ, "PYTHONPATH": str(REPO)}
STOPPED_STARTING = "stopped (Ctrl-C); served nothing (stopped while starting)"
#: Lines serve prints before Ctrl-C, which are not its answer to it.
SERVING_LINES = ("serving http://", "network: ", "--host ")
#: Fractions of the calibration run's time from start to its `serving` line.
START_FRACTIONS = (0.15, 0.3, 0.45, 0.6, 0.75, 0.9)
#: Native libraries mapped while serve starts, in order: numpy (cli.py's first heavy import),
#: scipy.ndimage's last (the end of cli.py's imports), drjit (Mitsuba loading in the path
#: tracer's thread), libLLVM (the G-buffers' kernels compiling).
START_POINTS = ("_multiarray_umath", "_ni_label", "_drjit_ext", "libLLVM")


class Served:
    """`shaderball serve --port 0` as a user runs it, its stderr lines read as they come."""

    def __init__(self, *args: str):
        self.started = time.monotonic()
        self.proc = started([str(SCRIPT), "serve", "--port", "0", *args], env=SCRIPT_ENV, text=False)
        self.lines: list[str] = []
        self.out = b""
        self.keep = None  # a connection held open until the process ends
        self.changed = threading.Condition()
        self.readers = [threading.Thread(target=self._read_err), threading.Thread(target=self._read_out)]
        for reader in self.readers:
            reader.start()

    def _read_err(self) -> None:
        for raw in self.proc.stderr:
            with self.changed:
                self.lines.append(raw.decode("utf-8", "replace").rstrip("\n"))
                self.changed.notify_all()

    def _read_out(self) -> None:
        self.out = self.proc.stdout.read()

    def url(self) -> str:
        """The address of the `serving` line, once it came."""
        with self.changed:
            while not any(line.startswith("serving http://") for line in self.lines):
                assert self.readers[0].is_alive(), f"serve ended before serving: {self.lines}"
                self.changed.wait(0.5)
            return next(line.split()[1] for line in self.lines if line.startswith("serving http://"))

    def wait_mapped(self, library: str) -> bool:
        """Wait until a native library whose file name holds ``library`` is mapped; False if the
        process ended first."""
        while self.proc.poll() is None:
            if has_mapped(self.proc.pid, library):
                return True
            time.sleep(0.002)
        return False

    def interrupt(self) -> float:
        sent = time.monotonic()
        os.killpg(self.proc.pid, signal.SIGINT)
        return sent

    def finish(self) -> tuple[int, list[str], str, float]:
        """(exit code, stderr lines, stdout, time it ended)."""
        try:
            self.proc.wait(600)
        finally:
            ended = time.monotonic()
            if self.proc.poll() is None:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
            for reader in self.readers:
                reader.join(60)
        return self.proc.returncode, self.lines, self.out.decode("utf-8", "replace"), ended


def _answer(lines: list[str]) -> list[str]:
    """What serve said after its start-up lines: its answer to Ctrl-C."""
    return [line for line in lines if line.strip() and not line.startswith(SERVING_LINES)]


def _one_line_and_130(what: str, code: int, lines: list[str], out: str) -> str:
    said = _answer(lines)
    assert code == 130 and out == "", (what, code, lines, out)
    assert not any("Traceback" in line or "Error" in line for line in lines), (what, lines)
    assert len(said) == 1, (what, lines)
    assert said[0] in (INTERRUPTED_MESSAGE, STOPPED_STARTING) or said[0].startswith("stopped (Ctrl-C); served http://")
    return said[0]


def _view(client: str) -> bytes:
    doc = {
        "client": client,
        "material": {"kind": "uniform"},
        "light": {"azimuth_deg": 100.0, "elevation_deg": 40.0, "turbidity": 3.0},
        "exposure": 4.0,
    }
    return json.dumps(doc).encode()


def _big_png() -> bytes:
    """An upload that takes the server a while to read and decode: 1400 x 1400 RGB noise, stored
    (it does not compress), under the 8 MiB limit."""
    import io

    from PIL import Image

    pixels = np.random.default_rng(7).integers(0, 256, (1400, 1400, 3), dtype=np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="PNG", compress_level=0)
    return buffer.getvalue()


def _in_background(call) -> None:
    def run():
        try:
            call()
        except OSError:
            pass  # the server stopped mid-request: what the test does

    threading.Thread(target=run, daemon=True).start()


# --------------------------------------------------------------------------- as a process


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize(
    "args, library",
    [
        (("serve", "--port", "0"), "_multiarray_umath"),
        (("serve", "--port", "0"), "_imaging"),
        (("validate", "/nonexistent", "--json"), "_multiarray_umath"),
        (("plan", "manifests/smoke.toml"), "_ni_label"),
    ],
    ids=["serve-numpy", "serve-pil", "validate-json-numpy", "plan-scipy"],
)
def test_ctrl_c_while_the_script_imports_cli_is_one_line_and_130(args, library):
    """The `shaderball` script imports cli.py (it does not run it as __main__): Ctrl-C once a
    native library of cli.py's imports is mapped, so while they go on."""
    proc = started([str(SCRIPT), *args], env=SCRIPT_ENV)
    try:
        while proc.poll() is None and not has_mapped(proc.pid, library):
            time.sleep(0.001)
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=600)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130 and "Traceback" not in err, err
    assert [line for line in err.splitlines() if line.strip()] == [INTERRUPTED_MESSAGE], err
    if "--json" in args:
        doc = {"error": INTERRUPTED_MESSAGE, "exit": 130, "ok": False}
        assert out == json.dumps(doc, indent=1, sort_keys=True) + "\n", out  # as every --json document is written
    else:
        assert out == ""


SPAWNING_MAIN = """
import signal
import cli  # as the `shaderball` script imports it
import multiprocessing

def child(queue):
    queue.put(signal.getsignal(signal.SIGINT) is signal.default_int_handler)

if __name__ == "__main__":
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    process = context.Process(target=child, args=(queue,))
    process.start()
    print(signal.getsignal(signal.SIGINT) is signal.default_int_handler, queue.get(timeout=600))
    process.join()
"""


def test_the_handler_is_the_commands_not_that_of_a_process_it_spawns(tmp_path):
    """Imported as the script imports it, cli.py takes Ctrl-C over until a command's body runs;
    a process the command spawns (a rank of `train --devices N`) imports cli.py again, as its
    parent's main module, and keeps Python's own handler."""
    main = tmp_path / "spawning.py"
    main.write_text(SPAWNING_MAIN)
    done = subprocess.run(
        [sys.executable, str(main)],
        cwd=REPO,
        env=SCRIPT_ENV,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0 and done.stdout.split() == ["False", "True"], (done.stdout, done.stderr)


def _calibrated_start_s() -> float:
    """Seconds from start to the `serving` line, on this machine now."""
    served = Served()
    try:
        served.url()
        return time.monotonic() - served.started
    finally:
        served.interrupt()
        served.finish()


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_ctrl_c_at_any_moment_from_start_to_serving_is_one_line_and_130():
    """Ctrl-C at moments spread from the process's start (fractions of a calibration run's time
    to `serving`) and at fixed points of start-up, then idle, mid-render (a view just posted;
    a view whose first pass is shown) and mid-upload (a big PNG decoding): exit code 130 and one
    line every time, no traceback, nothing on stdout. Prints each run's stop time."""
    start_s = _calibrated_start_s()
    moments = [
        (f"{f:.0%} of start-up", lambda s, f=f: time.sleep(max(0.0, s.started + f * start_s - time.monotonic())))
        for f in START_FRACTIONS
    ]
    moments += [(f"{lib} mapped", lambda s, lib=lib: s.wait_mapped(lib)) for lib in START_POINTS]
    moments += [("idle", lambda s: s.url()), ("view posted", _view_posted), ("first pass shown", _first_pass)]
    moments += [("upload half sent", _upload_sent(0.5)), ("upload sent", _upload_sent(1.0))]
    ends = []
    for what, reach in moments:
        served = Served()
        try:
            reach(served)
        finally:
            sent = served.interrupt()
        code, lines, out, ended = served.finish()
        ends.append((what, ended - sent, _one_line_and_130(what, code, lines, out)))
    print(f"\nserve start-up to `serving`: {start_s:.2f} s (calibration); Ctrl-C to the process's end:")
    for what, seconds, said in ends:
        print(f"  {what:28s} {seconds:6.2f} s  {said[:60]}")


def _view_posted(served: Served) -> None:
    status, _, _ = Client(served.url()).request("POST", "/api/view", _view("cc"), {"Content-Type": "application/json"})
    assert status == 200


def _first_pass(served: Served) -> None:
    client = Client(served.url())
    status, doc = client.view("cc")
    assert status == 200
    client.wait_frame("cc", doc["generation"], lambda f: "path" in f)


def _upload_sent(share: float):
    """A moment mid-upload: ``share`` of a big PNG's body sent on a connection of its own (the
    server reading it; all of it: reading the last bytes or decoding)."""

    def reach(served: Served) -> None:
        body = _big_png()
        host, port = served.url().split("//")[1].rstrip("/").split(":")
        head = (
            f"POST /api/upload?client=up&map=diffuse HTTP/1.1\r\nHost: {host}:{port}\r\n"
            f"Content-Type: image/png\r\nContent-Length: {len(body)}\r\n\r\n"
        ).encode()
        sock = socket.create_connection((host, int(port)), timeout=600)
        served.keep = sock  # open until the process ends
        sock.sendall(head + body[: int(len(body) * share)])

    return reach


# --------------------------------------------------------------------------- in the process


def test_a_render_under_way_at_ctrl_c_is_abandoned_not_finished(monkeypatch):
    """serve() in this process's main thread, a render held under way (the path tracer's second
    call, which would complete the 4 spp pass, waits at its start until the test lets it go), and
    Ctrl-C: serve() ends with the render still held, naming the path tracer among the threads it
    left; let go afterwards, the render's pass is never published."""
    from pipeline.serve import server
    from pipeline.serve.workers import PathTracer
    from pipeline.ui.interrupt import Stopped

    calls, held, let_go, tracers = [], threading.Event(), threading.Event(), []
    render_pass = PathTracer.render_pass

    def gated(self, job):
        calls.append(job.client)
        tracers.append(self)
        if len(calls) == 2:
            held.set()
            let_go.wait(900)
        return render_pass(self, job)

    monkeypatch.setattr(PathTracer, "render_pass", gated)
    urls, errors = [], []

    def drive():
        try:
            while not urls:
                time.sleep(0.01)
            client = Client(urls[0])
            status, doc = client.view("held")
            assert status == 200, doc
            client.wait_frame("held", doc["generation"], lambda f: "path" in f)  # the 1 spp pass
            held.wait(900)
        except Exception as exc:  # noqa: BLE001 - asserted below, once serve() has stopped
            errors.append(exc)
        finally:
            os.kill(os.getpid(), signal.SIGINT)  # the main thread's handler: serve()'s

    driver = threading.Thread(target=drive, daemon=True)
    driver.start()
    previous = signal.getsignal(signal.SIGINT)
    try:
        with pytest.raises(Stopped) as stopped:
            server.serve(server.ServeOptions(port=0), ready=lambda lines: urls.append(lines[0].split()[1]))
        still_held = not let_go.is_set()
    finally:
        let_go.set()
        signal.signal(signal.SIGINT, previous)  # serve() leaves its own in place when it left threads
    assert errors == []
    tracer = tracers[0]
    tracer.join(600)
    assert not tracer.is_alive() and len(calls) == 2
    frame = tracer.hub.clients["held"].frame
    assert frame["path"]["spp"] == 1, frame["path"]  # the 4 spp pass rendered after Ctrl-C: dropped
    assert still_held and "shaderball-path-tracer" in getattr(stopped.value, "left_running", ()), stopped.value
