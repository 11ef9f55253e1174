"""Path tracing beside the network in an evaluation: low-spp renders of a dataset's sample
with its own material, light and settings and a seed of their own (:class:`PathTracer`), and
the spp whose render takes the network's CPU time on this machine (equal time: CPU times at
two spp, a line through them solved for the network's time)."""

from __future__ import annotations

import time

import numpy as np

from geometry import build_shaderball, default_camera
from materials import MaterialMaps
from materials.brdf_ref import DEFAULT_MODEL
from pipeline.check.inspect import TEXTURE_LAYERS
from pipeline.neural import speed
from pipeline.neural.data import box_downsample
from pipeline.neural.infer import run_network
from pipeline.neural.limits import SPP_LADDER_RANGE
from pipeline.render.renderer import RenderSettings, render_sample
from sky import Light

#: Low-spp renders get seeds of their own: this plus the spp, beside the record's seed.
PT_SEED_OFFSET = 0x5EED
#: spp at which path tracing's CPU time is measured to fit t(spp) = a + b spp (equal time).
EQUAL_TIME_PROBE_SPP = (1, 64)
#: Each probe is timed this many times and the least CPU time kept: other work on the machine
#: only adds time (spinning threads, cache), so the minimum is the cost (measured: a median of
#: 3 taken beside two training runs gave the network 0.42 s instead of 0.018 s, and 8 spp less
#: time than 1, which sent the fit to 4096 spp).
EQUAL_TIME_REPEATS = 5


def cpu_timed(fn, *args):
    """(result, CPU seconds of this process: every thread, Mitsuba's and torch's, counted)."""
    started = time.process_time()
    out = fn(*args)
    return out, time.process_time() - started


def equal_time_spp(network_cpu_s: float, probe: dict[int, float], hi: int = SPP_LADDER_RANGE[1]) -> int:
    """The spp whose render takes the network's CPU time, from CPU times at two spp
    (a line a + b spp through them); at least 1, at most ``hi``. A probe whose larger spp took
    no more time than its smaller (noise) gives 1 spp to a network faster than either render
    and otherwise charges the larger probe's whole time per spp (no fixed part): fewer spp,
    never a runaway to ``hi``."""
    (s0, t0), (s1, t1) = sorted(probe.items())
    per_spp = (t1 - t0) / (s1 - s0)
    fixed = t0 - per_spp * s0
    if per_spp <= 0 or fixed < 0:
        if network_cpu_s <= min(t0, t1):  # faster than any render
            return 1
        per_spp, fixed = t1 / s1, 0.0
    return int(min(hi, max(1, round((network_cpu_s - fixed) / per_spp))))


def pt_cpu_time(probe: dict[int, float], spp: int) -> float:
    """Path tracing's CPU time at ``spp`` on the line :func:`equal_time_spp` solves (its time
    per spp alone, when the larger probe took no more time)."""
    (s0, t0), (s1, t1) = sorted(probe.items())
    per_spp = (t1 - t0) / (s1 - s0)
    fixed = t0 - per_spp * s0
    if per_spp <= 0 or fixed < 0:
        per_spp, fixed = t1 / s1, 0.0
    return fixed + per_spp * spp


class PathTracer:
    """Low-spp renders of a dataset's sample, with the sample's material, light and settings,
    under ``variant`` (resolved once by the caller)."""

    def __init__(self, dataset, variant: str):
        """``dataset``: opened (pipeline.neural.data), its records and texture maps read."""
        self.dataset, self.factor, self.variant = dataset, dataset.factor, variant
        self.ball, self.camera = build_shaderball(), default_camera()
        self.warm = False

    def material(self, sample) -> MaterialMaps | None:
        """The sample's texture-space maps (its texture file), or None if the dataset stores none."""
        if sample.texture is None:
            return None
        layers = self.dataset.read_layers(sample.texture, TEXTURE_LAYERS)
        return MaterialMaps(layers["diffuse"], layers["specular"], layers["roughness"][..., 0], layers["normal"])

    def render(self, record: dict, maps, spp: int, seed: int | None = None) -> tuple[np.ndarray, float]:
        """(image at the network's resolution, seconds) of the sample at ``spp``; ``seed``: the
        render's own (default: the record's render seed, offset by PT_SEED_OFFSET and ``spp``)."""
        r = record["render"]
        settings = RenderSettings(
            resolution=r["resolution"],
            spp=spp,
            max_depth=r["max_depth"],
            integrator=r["integrator"],
            sun=r["sun"],
            variant=self.variant,
            model=r.get("model", DEFAULT_MODEL),
        )  # absent: the default model
        light = Light.from_dict(record["lighting"]["requested"])
        if seed is None:
            seed = (int(record["seeds"]["render"]) + PT_SEED_OFFSET + spp) % 2**32
        if not self.warm:  # the first render compiles kernels: keep that out of the timings
            render_sample(self.ball, self.camera, maps, light, settings, seed)
            self.warm = True
        result = render_sample(self.ball, self.camera, maps, light, settings, seed)
        image = box_downsample(np.asarray(result.image, dtype=np.float32), self.factor)
        return image, float(result.stats["time_s"])


def measure_equal_time(model, item, sample, tracer, record, maps, device) -> dict:
    """The spp at which a render takes the network's CPU time per image on this machine: the
    least of EQUAL_TIME_REPEATS CPU times of the network (one torch thread: an idle intra-op
    thread spins, so on a loaded machine two threads' CPU time was 20x the work) and of path
    tracing at each of EQUAL_TIME_PROBE_SPP (kernels compiled first)."""
    args = (model, item["maps"].numpy(), sample.lighting_vector, device)
    with speed.torch_threads(1):  # idle threads spin: beside other work 2 threads burnt 0.40 s CPU, not 0.018
        network_all = [cpu_timed(run_network, *args)[1] for _ in range(EQUAL_TIME_REPEATS)]
    tracer.render(record, maps, EQUAL_TIME_PROBE_SPP[0])  # compiles and warms
    probe_all = {
        spp: [cpu_timed(tracer.render, record, maps, spp)[1] for _ in range(EQUAL_TIME_REPEATS)]
        for spp in EQUAL_TIME_PROBE_SPP
    }
    probe = {spp: min(times) for spp, times in probe_all.items()}
    network_cpu_s = min(network_all)
    lo, hi = EQUAL_TIME_PROBE_SPP
    spp = equal_time_spp(network_cpu_s, probe)
    return {
        "spp": spp,
        "network_cpu_s": network_cpu_s,
        "pt_cpu_s_at_spp": pt_cpu_time(probe, spp),
        "pt_cpu_s": {str(k): v for k, v in probe.items()},
        "network_cpu_s_all": network_all,
        "pt_cpu_s_all": {str(k): v for k, v in probe_all.items()},
        "how": f"CPU time of this process (every thread) per image, measured on the first sample: the least of "
        f"{EQUAL_TIME_REPEATS} runs of the network (one torch thread) and of path tracing at {lo} and {hi} spp; a line through the two "
        "solved for the network's time (if the larger spp took no more time, its time per spp with no fixed part)",
    }
