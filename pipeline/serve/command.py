"""`shaderball serve` and `shaderball serve --benchmark`: one function the CLI calls.

The benchmark (``ServeOptions.benchmark``) drives the server's own machinery (the hub, the
Mitsuba thread, the network thread) without HTTP: it moves the sun azimuth ``repeats`` times,
as a slider drag does, and times each move to the network's picture and to the first
path-traced pass.
"""

from __future__ import annotations

import os
import statistics
import time
from dataclasses import dataclass

from pipeline.serve.materials import uniform_maps
from pipeline.serve.server import App, ServeOptions, serve
from pipeline.serve.view import UniformChoice, View
from pipeline.serve.work import NetworkRunner
from sky import Light

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
                f"(median; min {n['network_min_ms']:.1f}), slider to picture {n['latency_ms']:.1f} ms"
            )
        else:
            out.append("network: none (--run RUN to time one)")
        p = self.path
        out.append(
            f"path tracing at {p['resolution']} px: first pass (1 spp) {p['first_pass_s']:.3f} s (median; "
            f"min {p['first_pass_min_s']:.3f}), slider to picture {p['latency_s']:.3f} s"
        )
        return out


def _wait(app: App, client: str, generation: int, part: str, timeout_s: float = 120.0) -> dict:
    deadline, since = time.monotonic() + timeout_s, 0
    while time.monotonic() < deadline:
        frame = app.hub.frame(client, since, 1.0)
        since = frame["version"]
        if frame.get("generation") == generation and part in frame:
            return frame[part]
        if frame.get("generation") == generation and "error" in frame:
            raise RuntimeError(frame["error"]["message"])
    raise TimeoutError(f"no {part} frame within {timeout_s:.0f} s")


def benchmark(options: ServeOptions, network_loader=None) -> BenchmarkSummary:
    """``options.repeats`` sun moves timed (module docstring)."""
    repeats = options.repeats
    network = network_loader() if network_loader is not None else None
    app = App(options, network)
    app.tracer.start()
    app.tracer.ready.wait()
    if app.tracer.failure is not None:
        raise app.tracer.failure
    if network is not None:
        app.runner = NetworkRunner(app.hub, network, lambda: app.tracer.network_gbuffer)
        app.runner.start()
    material = UniformChoice((0.6, 0.3, 0.2), 0.04, 0.3, False, 0.0)
    maps = uniform_maps(material)
    net_ms, net_latency, first, first_latency = [], [], [], []
    try:
        for i in range(repeats + 1):  # the first move compiles the kernels: not counted
            view = View(material, Light(45.0, 200.0 + 10.0 * i, 3.0), 4.0)
            generation = app.hub.submit("bench", view, lambda: maps)
            path = _wait(app, "bench", generation, "path")
            net = _wait(app, "bench", generation, "network") if network is not None else None
            if i == 0:
                continue
            first.append(path["pass_s"])
            first_latency.append(path["seconds"])
            if net is not None:
                net_ms.append(net["network_ms"])
                net_latency.append(net["latency_ms"])
    finally:
        app.close()
    network_doc = None
    if network is not None:
        network_doc = {
            "resolution": network.resolution,
            "threads": network.describe()["threads"],
            "network_ms": statistics.median(net_ms),
            "network_min_ms": min(net_ms),
            "latency_ms": statistics.median(net_latency),
        }
    path_doc = {
        "resolution": app.hub.path_resolution,
        "first_pass_s": statistics.median(first),
        "first_pass_min_s": min(first),
        "latency_s": statistics.median(first_latency),
    }
    return BenchmarkSummary(network_doc, path_doc, list(os.getloadavg()), os.cpu_count() or 1, repeats)


def serve_command(options: ServeOptions, network_loader, say):
    """Serve until Ctrl-C (``say`` is told the address), or with ``options.benchmark`` run the
    benchmark; a summary with lines()."""
    if options.benchmark:
        return benchmark(options, network_loader)
    return serve(options, network_loader, ready=lambda lines: [say(line) for line in lines])
