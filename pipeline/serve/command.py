"""`shaderball serve` and `shaderball serve --benchmark`: one function the CLI calls.

The benchmark (``ServeOptions.benchmark``) starts the server on a free loopback port and moves
the sun azimuth ``repeats`` times through HTTP, as the page does on a slider drag: it posts the
view and long-polls for its frames (:class:`PageClient`). Each move is timed twice: in the
server (from the view's arrival to the network's picture and to the first path-traced pass:
the work) and in the client (from the POST to the frame that carries the picture: what the page
sees, JSON, PNG and the poll included).
"""

from __future__ import annotations

import http.client
import json
import os
import statistics
import time
from dataclasses import dataclass, replace
from urllib.parse import urlsplit

from pipeline.serve.server import App, ServeOptions, serve

__all__ = ["ServeOptions", "serve_command", "benchmark"]


@dataclass
class BenchmarkSummary:
    network: dict | None
    path: dict
    load: list[float]
    cpus: int
    repeats: int

    def lines(self) -> list[str]:
        load = ", ".join(f"{x:.2f}" for x in self.load)
        out = [f"serve benchmark: {self.repeats} sun moves, {self.cpus} CPUs, load average {load}"]
        if self.network is not None:
            n = self.network
            out.append(
                f"network at {n['resolution']} px ({n['threads']} torch threads): {n['network_ms']:.1f} ms a frame "
                f"(median; min {n['network_min_ms']:.1f}), slider to picture {n['latency_ms']:.1f} ms in the server, "
                f"{n['http_latency_ms']:.1f} ms through HTTP"
            )
        else:
            out.append("network: none (--run RUN to time one)")
        p = self.path
        out.append(
            f"path tracing at {p['resolution']} px: first pass (1 spp) {p['first_pass_s']:.3f} s (median; "
            f"min {p['first_pass_min_s']:.3f}), slider to picture {p['latency_s']:.3f} s in the server, "
            f"{p['http_latency_s']:.3f} s through HTTP"
        )
        return out


class PageClient:
    """The page's side of HTTP, as page.html does it: a view posted to /api/view, then
    /api/frame long-polled until the parts of that view's generation arrive; times are taken
    here, in the client, so they hold everything the page waits for (JSON, PNG, the poll)."""

    def __init__(self, url: str, timeout_s: float = 120.0):
        parts = urlsplit(url)
        self.conn = http.client.HTTPConnection(parts.hostname, parts.port, timeout=timeout_s)
        self.timeout_s = timeout_s

    def _json(self, method: str, path: str, doc: dict | None = None) -> dict:
        body = json.dumps(doc).encode() if doc is not None else None
        headers = {"Content-Type": "application/json"} if body is not None else {}
        self.conn.request(method, path, body=body, headers=headers)
        response = self.conn.getresponse()
        answer = json.loads(response.read())
        if response.status != 200:
            raise RuntimeError(f"{method} {path}: {response.status} {answer.get('error')}")
        return answer

    def view(self, doc: dict) -> int:
        return self._json("POST", "/api/view", doc)["generation"]

    def arrivals(self, client: str, generation: int, parts: tuple[str, ...]) -> dict[str, tuple[dict, float]]:
        """Each of ``parts`` of ``generation`` as first seen: (its document, perf_counter then)."""
        deadline, since, seen = time.monotonic() + self.timeout_s, 0, {}
        while len(seen) < len(parts):
            if time.monotonic() > deadline:
                raise TimeoutError(f"no {', '.join(p for p in parts if p not in seen)} within {self.timeout_s:.0f} s")
            frame = self._json("GET", f"/api/frame?client={client}&since={since}")
            now, since = time.perf_counter(), frame["version"]
            if frame.get("generation") != generation:
                continue
            if "error" in frame:
                raise RuntimeError(frame["error"]["message"])
            seen.update({p: (frame[p], now) for p in parts if p in frame and p not in seen})
        return seen

    def close(self) -> None:
        self.conn.close()


def _view_doc(client: str, move: int) -> dict:
    """The benchmark's material under a sun moved ``move`` steps of 10 degrees, as the page posts it."""
    return {
        "client": client,
        "material": {"kind": "uniform", "diffuse": [0.6, 0.3, 0.2], "specular": 0.04, "roughness": 0.3},
        "light": {"elevation_deg": 45.0, "azimuth_deg": 200.0 + 10.0 * move, "turbidity": 3.0},
        "exposure": 4.0,
    }


def benchmark(options: ServeOptions, network_loader=None) -> BenchmarkSummary:
    """``options.repeats`` sun moves timed through HTTP (module docstring)."""
    network = network_loader() if network_loader is not None else None
    app = App(replace(options, host="127.0.0.1", port=0), network).start()
    app.serve_in_thread()
    page = PageClient(app.url)
    parts = ("path", "network") if network is not None else ("path",)
    times: dict[str, list[float]] = {
        k: [] for k in ("first", "path_latency", "path_http", "net", "net_latency", "net_http")
    }
    try:
        for i in range(options.repeats + 1):  # the first move compiles the kernels: not counted
            posted = time.perf_counter()
            seen = page.arrivals("bench", page.view(_view_doc("bench", i)), parts)
            if i == 0:
                continue
            path, path_at = seen["path"]
            times["first"].append(path["pass_s"])
            times["path_latency"].append(path["seconds"])
            times["path_http"].append(path_at - posted)
            if network is not None:
                net, net_at = seen["network"]
                times["net"].append(net["network_ms"])
                times["net_latency"].append(net["latency_ms"])
                times["net_http"].append((net_at - posted) * 1000)
    finally:
        page.close()
        app.close()
    median = {k: statistics.median(v) for k, v in times.items() if v}
    network_doc = None
    if network is not None:
        network_doc = {
            "resolution": network.resolution,
            "threads": network.describe()["threads"],
            "network_ms": median["net"],
            "network_min_ms": min(times["net"]),
            "latency_ms": median["net_latency"],
            "http_latency_ms": median["net_http"],
        }
    path_doc = {
        "resolution": app.hub.path_resolution,
        "first_pass_s": median["first"],
        "first_pass_min_s": min(times["first"]),
        "latency_s": median["path_latency"],
        "http_latency_s": median["path_http"],
    }
    return BenchmarkSummary(network_doc, path_doc, list(os.getloadavg()), os.cpu_count() or 1, options.repeats)


def serve_command(options: ServeOptions, *, say, network=None, stored=None):
    """Serve until Ctrl-C (``say`` is told the address), or with ``options.benchmark`` run the
    benchmark; a summary with lines(). ``network``: a function of ``options`` giving the
    network of ``options.run`` (pipeline.neural.command.live_network), called where there is
    a run; ``stored``: a function of a dataset root giving its stored renders, used where
    there is ``options.dataset``."""
    network_loader = (lambda: network(options)) if network is not None and options.run is not None else None
    stored = stored if options.dataset is not None else None
    if options.benchmark:
        return benchmark(options, network_loader)
    return serve(options, network_loader, ready=lambda lines: [say(line) for line in lines], stored=stored)
