"""A headless Chromium (Debian's `chromium`) driven over the Chrome DevTools protocol through
a pipe (``--remote-debugging-pipe``: NUL-separated JSON on file descriptors 3 and 4), with
the standard library only: no driver binary to match to the browser, no websocket client.
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import queue
import shutil
import subprocess
import threading
import time

CHROMIUM_NAMES = ("chromium", "chromium-browser")
#: The flags a root-run headless Chromium needs here, and no network of its own.
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--remote-debugging-pipe",
)


def chromium_path() -> str | None:
    return next((p for p in map(shutil.which, CHROMIUM_NAMES) if p), None)


def unavailable_reason() -> str | None:
    """Why no headless browser test can run here, or None when it can."""
    if chromium_path() is None:
        return (
            "headless Chromium not available: chromium not found (`make chromium`, part of `make test`, "
            "installs Debian's chromium as root with apt-get)"
        )
    return None


class Browser:
    """One page in a headless Chromium; :meth:`call` sends a command to it and waits for the answer."""

    def __init__(self, user_data_dir: str, width: int = 1000, height: int = 900):
        cmd_r, self._cmd_w = os.pipe()
        self._res_r, res_w = os.pipe()
        args = [*FLAGS, f"--user-data-dir={user_data_dir}", f"--window-size={width},{height}", "about:blank"]
        self.proc = subprocess.Popen(
            ["bash", "-c", f'exec "$0" "$@" 3<&{cmd_r} 4>&{res_w}', chromium_path(), *args],
            pass_fds=(cmd_r, res_w),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        os.close(cmd_r)
        os.close(res_w)
        self._answers: dict[int, queue.Queue] = {}
        self._lock = threading.Lock()
        self._next = 0
        threading.Thread(target=self._read, daemon=True).start()
        target = self.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        self.session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        self.call("Page.enable", session=True)
        self.call(
            "Emulation.setDeviceMetricsOverride",
            {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False},
            session=True,
        )

    def _read(self) -> None:
        buffer = b""
        while chunk := os.read(self._res_r, 1 << 16):
            buffer += chunk
            while b"\0" in buffer:
                message, buffer = buffer.split(b"\0", 1)
                doc = json.loads(message)
                if "id" in doc:
                    with self._lock:
                        box = self._answers.get(doc["id"])
                    if box is not None:
                        box.put(doc)

    def call(self, method: str, params: dict | None = None, session: bool = False, timeout_s: float = 120.0) -> dict:
        with self._lock:
            self._next += 1
            ident = self._next
            box = self._answers[ident] = queue.Queue()
        message = {"id": ident, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = self.session
        os.write(self._cmd_w, json.dumps(message).encode() + b"\0")
        try:
            doc = box.get(timeout=timeout_s)
        except queue.Empty:
            raise TimeoutError(f"Chromium did not answer {method} within {timeout_s} s") from None
        if "error" in doc:
            raise RuntimeError(f"{method}: {doc['error']}")
        return doc["result"]

    def evaluate(self, expression: str):
        result = self.call("Runtime.evaluate", {"expression": expression, "returnByValue": True}, session=True)
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def navigate(self, url: str) -> None:
        self.call("Page.navigate", {"url": url}, session=True)

    def wait_for(self, expression: str, timeout_s: float = 240.0, every_s: float = 0.2):
        """The value of ``expression`` once it is truthy."""
        deadline, last = time.monotonic() + timeout_s, None
        while time.monotonic() < deadline:
            try:
                value = self.evaluate(expression)
            except RuntimeError as exc:  # the page is still loading: its elements are not there yet
                value, last = None, exc
            if value:
                return value
            time.sleep(every_s)
        raise TimeoutError(f"not true within {timeout_s} s: {expression}" + (f" (last: {last})" if last else ""))

    def drag(self, x0: float, y0: float, x1: float, y1: float, steps: int = 8) -> None:
        """Press the mouse at (x0, y0), move to (x1, y1) in ``steps``, release: a slider drag."""
        mouse = lambda kind, x, y, **more: self.call(  # noqa: E731
            "Input.dispatchMouseEvent", {"type": kind, "x": x, "y": y, **more}, session=True
        )
        mouse("mouseMoved", x0, y0)
        mouse("mousePressed", x0, y0, button="left", clickCount=1)
        for i in range(1, steps + 1):
            mouse("mouseMoved", x0 + (x1 - x0) * i / steps, y0 + (y1 - y0) * i / steps, button="left", buttons=1)
        mouse("mouseReleased", x1, y1, button="left", clickCount=1)

    def screenshot(self) -> bytes:
        return base64.b64decode(self.call("Page.captureScreenshot", {"format": "png"}, session=True)["data"])

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.call("Browser.close", timeout_s=10)
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.proc.wait(10)
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        os.close(self._cmd_w)
