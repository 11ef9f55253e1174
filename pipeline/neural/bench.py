"""`shaderball train DATASET --benchmark`: loader, training and inference rates.

- loader: EXR reading, SHA-256 check, decoding and assembly of every sample of the
  dataset through a DataLoader with the given workers, from a fresh dataset object (so
  the per-process maps cache starts empty, as in a first epoch); DATASET may be a
  publication, whose opening (the reader's check of every tar) is timed apart. Its rate is
  the steady one, from the first batch on; the start-up before it (worker processes
  started, the first batch read) is said apart: over a few samples it would be most of
  the time;
- training: steps of the network with the chosen loss on random inputs at the dataset's
  network resolution (a randomly initialised VGG16 stands in for ImageNet weights: the
  rate does not depend on the weights' values);
- inference: the network at batch 1, mean of repeated timed calls after a warm-up.

``shaderball neural-bench loaders`` compares the loader alone on a dataset folder and its
publication (:func:`compare_loaders`): the same samples, best of a few passes each.
``shaderball neural-bench denoise`` compares what OIDN is fed (:func:`compare_denoisers`)
against fresh high-spp renders of the same samples. Each comparison takes its request
(:mod:`pipeline.neural.config`), whose fields are checked when it is built.
"""

from __future__ import annotations

import contextlib
import dataclasses
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass

import numpy as np
import torch
from torch.utils.data import DataLoader, default_collate

from pipeline.errors import quoted
from pipeline.fields import FieldError
from pipeline.image import metrics
from pipeline.image.denoise import denoise
from pipeline.image.tonemap import DEFAULT_EXPOSURE, hdr_to_srgb8
from pipeline.neural import speed
from pipeline.neural.config import CollateRequest, DenoiseRequest, LoadersRequest, TrainOptionsRequest
from pipeline.neural.data import collate_samples, open_dataset
from pipeline.neural.denoise import AuxBuffers
from pipeline.neural.equal_time import PathTracer
from pipeline.neural.evaluate import dataset_variant
from pipeline.neural.limits import TRAINING_VARIANTS
from pipeline.neural.loss import RenderLoss
from pipeline.neural.loss_choice import choose_loss
from pipeline.neural.network import NeuralRenderer
from pipeline.neural.train import TrainConfig, pick_device
from pipeline.neural.vgg import RELU3_3, random_vgg16_state_dict, vgg16_features
from pipeline.render.mitsuba_env import resolve_variant


@contextlib.contextmanager
def _naming(owner, name: str):
    """A dataset refused (the field ``dataset`` of pipeline.neural.data) as ``owner``'s field
    ``name``: loaders' folder and publication each by its own name."""
    try:
        yield
    except FieldError as exc:
        if exc.name != "dataset":
            raise
        raise owner.field_error(name, exc.value, exc.allowed, what=exc.what) from None


def _say(progress):
    return progress or (lambda message: None)


@dataclass
class BenchResult:
    resolution: int
    device: str
    workers: int
    loader_samples: int
    loader_samples_per_s: float | None  # steady: from the first batch on (None with one batch)
    loader_hash_checked: bool
    train_batch: int
    train_samples_per_s: float
    train_loss: str
    infer_ms: float
    threads: int
    source: str = "dataset folder"
    open_s: float = 0.0
    precision: str = "fp32"
    channels_last: bool = False
    #: seconds from the loader's start to its first batch (workers started, one batch read)
    loader_startup_s: float = 0.0
    #: samples in that first batch (left out of the steady rate)
    loader_startup_samples: int = 0
    #: every sample over the whole pass, start-up included
    loader_overall_samples_per_s: float = 0.0

    def lines(self) -> list[str]:
        steady = (
            f"{self.loader_samples_per_s:.1f} samples/s steady"
            if self.loader_samples_per_s is not None
            else "no steady rate (one batch only: pass more samples than --batch-size)"
        )
        return [
            f"loader: {steady} ({self.loader_samples} samples at "
            f"{self.resolution}x{self.resolution}, {self.workers} workers, SHA-256 "
            f"{'checked' if self.loader_hash_checked else 'not checked'}; from a {self.source}, opened in "
            f"{self.open_s:.2f} s{', every tar checked' if self.source == 'publication' else ''})",
            f"loader start-up: {self.loader_startup_s:.2f} s to the first batch ({self.loader_startup_samples} "
            f"samples, {self.workers} workers started); {self.loader_overall_samples_per_s:.1f} samples/s "
            "over the whole pass",
            f"training: {self.train_samples_per_s:.2f} samples/s (batch {self.train_batch}, {self.train_loss}, "
            f"{self.device}, {self.threads} torch threads, {self.precision}"
            f"{', channels-last' if self.channels_last else ''})",
            f"inference: {self.infer_ms:.1f} ms per image (batch 1, {self.device})",
        ]

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def _sync(device):
    if device.type == "cuda":
        torch.cuda.synchronize(device)


@dataclass
class LoaderRate:
    source: str  # "dataset folder" or "publication"
    open_s: float  # open_dataset (a publication: every tar checked)
    samples: int
    samples_per_s: float  # over the whole pass, start-up included
    resolution: int
    ids: list
    startup_s: float = 0.0  # from the loader's start to its first batch
    startup_samples: int = 0  # samples in the first batch
    #: samples after the first batch over the time since it arrived; None with one batch
    steady_samples_per_s: float | None = None


def loader_rate(config: TrainConfig) -> LoaderRate:
    return measure_loader(
        config.dataset,
        config.resolution,
        config.exposure,
        config.hash_check,
        config.batch_size,
        config.loader_workers,
    )


def measure_loader(
    root: str,
    resolution: int | None,
    exposure: float,
    check_hashes: bool,
    batch_size: int,
    workers: int,
    collate=collate_samples,
) -> LoaderRate:
    """Open ``root`` afresh and read every sample through a DataLoader (collated by ``collate``:
    the loader's own, or torch's ``default_collate`` to compare)."""
    started = time.perf_counter()
    dataset = open_dataset(root, resolution=resolution, exposure=exposure, check_hashes=check_hashes)
    open_s = time.perf_counter() - started
    loader = DataLoader(dataset, batch_size=batch_size, num_workers=workers, collate_fn=collate)
    started, count, ids = time.perf_counter(), 0, []
    first_at, first_count = None, 0
    for batch in loader:
        count += batch["maps"].shape[0]
        ids += batch["id"]
        if first_at is None:  # the iterator starts its workers, then waits for this batch
            first_at, first_count = time.perf_counter(), count
    ended = time.perf_counter()
    steady = (count - first_count) / (ended - first_at) if first_at is not None and count > first_count else None
    return LoaderRate(
        dataset.files.kind,
        open_s,
        count,
        count / (ended - started),
        dataset.resolution,
        ids,
        startup_s=(first_at if first_at is not None else ended) - started,
        startup_samples=first_count,
        steady_samples_per_s=steady,
    )


def bench_loss(config: TrainConfig, device) -> RenderLoss:
    """``config.loss`` with a randomly initialised VGG16 (the rate does not depend on weights)."""
    if config.loss == "l1+vgg":
        vgg = vgg16_features(upto=RELU3_3)
        vgg.load_state_dict(
            {
                k.removeprefix("features."): v
                for k, v in random_vgg16_state_dict(0).items()
                if int(k.split(".")[1]) <= RELU3_3
            }
        )
        loss_fn = RenderLoss("l1+vgg", vgg.eval().requires_grad_(False), config.vgg_weight).to(device)
    else:
        loss_fn = RenderLoss("l1").to(device)
    return loss_fn


class TrainingSteps:
    """Training steps of a fresh network with ``config``'s loss and speed options on random
    inputs at ``resolution``; the first (warm-up, compilation) step runs on construction."""

    def __init__(self, config: TrainConfig, device, resolution: int):
        self.config, self.device = config, device
        with speed.torch_threads(config.threads):
            self.model = NeuralRenderer(resolution, config.width).to(device)
            self.loss_fn = bench_loss(config, device)
            self.optimizer = torch.optim.Adam(self.model.parameters(), lr=config.lr)
            self.forward = speed.step_forward(self.model, self.loss_fn, config.channels_last, config.compile)
            self.scaler = speed.grad_scaler(device, config.precision)
            fmt = speed.memory_format(config.channels_last)
            n = config.batch_size
            self.maps = torch.rand(n, 12, resolution, resolution, device=device).to(memory_format=fmt)
            self.light = torch.rand(n, 4, device=device)
            self.target = torch.rand(n, 3, resolution, resolution, device=device).to(memory_format=fmt)
            self._step()
            _sync(device)

    def _step(self):
        self.optimizer.zero_grad(set_to_none=True)
        with speed.autocast(self.device, self.config.precision):
            loss = self.loss_fn(self.forward(self.maps, self.light), self.target)
        self.scaler.scale(loss).backward()
        self.scaler.step(self.optimizer)
        self.scaler.update()

    def samples_per_s(self, steps: int) -> float:
        with speed.torch_threads(self.config.threads):
            started = time.perf_counter()
            for _ in range(steps):
                self._step()
            _sync(self.device)
            return steps * self.config.batch_size / (time.perf_counter() - started)


def compare_training(req: TrainOptionsRequest, progress=None) -> dict:
    """Training samples/s of each of ``req.variants`` (``TRAINING_VARIANTS``' names; default
    all) beside the baseline (:meth:`TrainOptionsRequest.config`), each a fresh network warmed
    up first, then timed ``req.steps`` steps at a time, variants alternated ``req.repeats``
    times; medians, all passes and the load average after each round."""
    config, resolution, repeats, steps = req.config(), req.resolution, req.repeats, req.steps
    say = _say(progress)
    device = pick_device(config.device)
    names = list(req.variants or TRAINING_VARIANTS)
    runners, compile_s = {}, {}
    for name in names:
        variant = dataclasses.replace(config, **TRAINING_VARIANTS[name])
        variant = dataclasses.replace(variant, precision=speed.resolve_precision(variant.precision, device))
        say(f"warming up: {name}")
        started = time.perf_counter()
        runners[name] = TrainingSteps(variant, device, resolution)
        compile_s[name] = time.perf_counter() - started
    rates: dict[str, list[float]] = {name: [] for name in names}
    loads = []
    for k in range(repeats):
        say(f"pass {k + 1}/{repeats}")
        for name in names:
            rates[name].append(runners[name].samples_per_s(steps))
        loads.append(_load_average())
    base = statistics.median(rates[names[0]])
    return {
        "resolution": resolution,
        "device": str(device),
        "batch_size": config.batch_size,
        "loss": config.loss,
        "torch_threads": torch.get_num_threads(),
        "baseline_threads": config.threads,
        "repeats": repeats,
        "steps": steps,
        "load_average_1min": loads,
        "rows": [
            {
                "options": name,
                "samples_per_s_median": statistics.median(rates[name]),
                "samples_per_s_all": [round(r, 2) for r in rates[name]],
                f"ratio_to_{names[0]}": statistics.median(rates[name]) / base,
                "first_step_s": round(compile_s[name], 2),
            }
            for name in names
        ],
    }


def _load_average() -> str:
    try:
        with open("/proc/loadavg") as f:
            return f.read().split()[0]
    except OSError:
        return "?"


def benchmark(config: TrainConfig, steps: int = 5, infer_repeats: int = 10) -> BenchResult:
    """Loader, training and inference rates for ``config``; writes nothing."""
    device = pick_device(config.device)
    config = dataclasses.replace(config, precision=speed.resolve_precision(config.precision, device))
    if config.loss == "auto":  # the loss training would use (the rate depends on the kind, not the weights)
        config = dataclasses.replace(config, loss=choose_loss(config).name)
    loaded = loader_rate(config)
    resolution = loaded.resolution
    training = TrainingSteps(config, device, resolution)
    train_rate = training.samples_per_s(steps)
    model, maps, light = training.model, training.maps, training.light

    model.eval()
    with torch.no_grad():
        one, one_light = maps[:1], light[:1]
        model(one, one_light)
        _sync(device)
        started = time.perf_counter()
        for _ in range(infer_repeats):
            model(one, one_light)
        _sync(device)
        infer_ms = (time.perf_counter() - started) / infer_repeats * 1000
    return BenchResult(
        resolution,
        str(device),
        config.loader_workers,
        loaded.samples,
        loaded.steady_samples_per_s,
        config.hash_check,
        config.batch_size,
        train_rate,
        config.loss,
        infer_ms,
        speed.threads_for(config.threads),
        loaded.source,
        loaded.open_s,
        config.precision,
        config.channels_last,
        loaded.startup_s,
        loaded.startup_samples,
        loaded.samples_per_s,
    )


def compare_loaders(req: LoadersRequest, exposure: float = DEFAULT_EXPOSURE, progress=None) -> dict:
    """The loader's samples/s on a dataset folder and on its publication, passes alternated,
    best of ``req.repeats`` each (a shared machine's load only slows a pass); the publication's
    opening (every tar checked) is reported apart. Both must yield the same sample ids."""
    say = _say(progress)
    options = (req.resolution, exposure, req.hash_check, req.batch_size, req.loader_workers)
    runs: dict[str, list[LoaderRate]] = {"folder": [], "publication": []}
    for k in range(req.repeats):
        say(f"pass {k + 1}/{req.repeats}")
        with _naming(LoadersRequest, "folder"):
            runs["folder"].append(measure_loader(req.folder, *options))
        with _naming(LoadersRequest, "pub"):
            runs["publication"].append(measure_loader(req.pub, *options))
        if k == 0:
            _check_pair(req, runs["folder"][0], runs["publication"][0])
    out = {
        "samples": runs["folder"][0].samples,
        "resolution": runs["folder"][0].resolution,
        "workers": req.loader_workers,
        "batch_size": req.batch_size,
        "sha256_checked": req.hash_check,
        "repeats": req.repeats,
        "torch_threads": torch.get_num_threads(),
    }
    for name, rates in runs.items():
        out[name] = {
            "samples_per_s": max(r.samples_per_s for r in rates),
            "samples_per_s_all": [round(r.samples_per_s, 2) for r in rates],
            "open_s": min(r.open_s for r in rates),
        }
    return out


def _check_pair(req: LoadersRequest, folder: LoaderRate, pub: LoaderRate) -> None:
    """A dataset folder, then its publication: the same samples."""
    allowed = "a dataset folder, then its publication as {pub}"
    if folder.source != "dataset folder":
        raise LoadersRequest.field_error(
            "folder", req.folder, allowed, what=f"{quoted(req.folder)} is a {folder.source}"
        )
    if pub.source != "publication":
        raise LoadersRequest.field_error("pub", req.pub, allowed, what=f"{quoted(req.pub)} is a {pub.source}")
    if folder.ids != pub.ids:
        raise LoadersRequest.field_error(
            "pub",
            req.pub,
            "the publication of {folder}",
            what=f"{quoted(req.pub)} does not hold the samples of {quoted(req.folder)}",
        )


@contextlib.contextmanager
def busy_processes(count: int):
    """``count`` Python processes spinning on a core each, stopped on exit: a loaded machine."""
    spinners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]
    try:
        time.sleep(0.5 if count else 0.0)
        yield
    finally:
        for spinner in spinners:
            spinner.kill()
            spinner.wait()


COLLATIONS = {"torch default_collate": default_collate, "collate_samples (numpy, one thread)": collate_samples}


def compare_collation(
    req: CollateRequest, check_hashes: bool = True, exposure: float = DEFAULT_EXPOSURE, progress=None
) -> dict:
    """The loader's samples/s with torch's default collation and with :func:`collate_samples`,
    on the machine as it is and with ``req.busy`` spinning processes beside it; passes
    alternated (idle A, idle B, loaded A, loaded B, ...) ``req.repeats`` times; medians and
    all passes."""
    root, busy, repeats, batch_size = req.dataset, req.busy, req.repeats, req.batch_size
    workers, resolution = req.loader_workers, req.resolution
    say = _say(progress)
    rates: dict[tuple[str, str], list[float]] = {}
    loads = []
    for k in range(repeats):
        say(f"pass {k + 1}/{repeats}")
        for label, spinners in (("as is", 0), (f"{busy} busy processes", busy)):
            with busy_processes(spinners):
                for name, collate in COLLATIONS.items():
                    rate = measure_loader(root, resolution, exposure, check_hashes, batch_size, workers, collate)
                    rates.setdefault((label, name), []).append(rate.samples_per_s)
                loads.append(_load_average())
    rows = [
        {
            "machine": label,
            "collation": name,
            "samples_per_s_median": statistics.median(values),
            "samples_per_s_all": [round(v, 1) for v in values],
        }
        for (label, name), values in rates.items()
    ]
    return {
        "dataset": root,
        "samples": rate.samples,
        "resolution": rate.resolution,
        "workers": workers,
        "batch_size": batch_size,
        "repeats": repeats,
        "torch_threads": torch.get_num_threads(),
        "load_average_1min": loads,
        "rows": rows,
    }


#: What OIDN is fed, by row of :func:`compare_denoisers`: None, the colour alone; else
#: AuxBuffers' options (the last row is what `shaderball evaluate` uses).
DENOISE_VARIANTS = {
    "colour only": None,
    "pixel centres, material only (0 elsewhere)": {"supersample": 1, "surroundings": False},
    "pixel centres": {"supersample": 1},
    "4x4 centres, diffuse albedo d": {"albedo": "diffuse"},
    "4x4 centres (used)": {},
}


def compare_denoisers(req: DenoiseRequest, progress=None) -> dict:
    """Mean PSNR, SSIM (8-bit sRGB) and relMSE of OIDN's output against ``req.reference_spp``
    renders of ``req.draws`` samples drawn spread over the dataset (which must store texture
    maps), for each row of :data:`DENOISE_VARIANTS` and each of ``req.spp``."""
    root, samples, spps, reference_spp = req.dataset, req.draws, req.spp, req.reference_spp
    dataset = open_dataset(root)
    variant = resolve_variant(dataset_variant(dataset))
    tracer = PathTracer(dataset, variant)
    auxes = {
        name: AuxBuffers(tracer.ball, tracer.camera, dataset.resolution, variant, **options)
        for name, options in DENOISE_VARIANTS.items()
        if options is not None
    }
    picked = sorted({int(i) for i in np.linspace(0, len(dataset) - 1, min(samples, len(dataset))).round()})
    scores: dict[tuple[int, str], list] = {}
    for n, index in enumerate(picked, start=1):
        sample = dataset.samples[index]
        maps = tracer.material(sample)
        if maps is None:
            raise DenoiseRequest.field_error(
                "dataset",
                root,
                "a dataset built with storage.texture_maps = true (the comparison re-renders samples)",
                what=f"{quoted(root)} stores no texture maps",
            )
        record = dataset.records[sample.id]
        truth = tracer.render(record, maps, reference_spp)[0]
        truth8 = hdr_to_srgb8(truth, dataset.exposure)
        for spp in spps:
            noisy = tracer.render(record, maps, spp)[0]
            for name in DENOISE_VARIANTS:
                aux = auxes.get(name)
                out = denoise(noisy)[0] if aux is None else denoise(noisy, aux.albedo(maps), aux.normal)[0]
                out8 = hdr_to_srgb8(out, dataset.exposure)
                scores.setdefault((spp, name), []).append(
                    (metrics.psnr8(out8, truth8), metrics.ssim8(out8, truth8), metrics.relmse(out, truth))
                )
        if progress is not None:
            progress(f"sample {n}/{len(picked)} {sample.id}")
    rows = [
        {
            "spp": spp,
            "fed": name,
            "psnr": float(np.mean([v[0] for v in values])),
            "ssim": float(np.mean([v[1] for v in values])),
            "relmse": float(np.mean([v[2] for v in values])),
        }
        for (spp, name), values in scores.items()
    ]
    return {
        "dataset": root,
        "samples": [dataset.samples[i].id for i in picked],
        "reference_spp": reference_spp,
        "resolution": dataset.resolution,
        "rows": rows,
    }


def denoise_table(result: dict) -> str:
    lines = ["| spp | OIDN fed | PSNR (dB) | SSIM | relMSE |", "|---|---|---|---|---|"]
    for row in result["rows"]:
        lines.append(f"| {row['spp']} | {row['fed']} | {row['psnr']:.2f} | {row['ssim']:.4f} | {row['relmse']:.5f} |")
    return "\n".join(lines) + "\n"


def _loader_table(result: dict, which: str, columns: tuple[str, ...], rows: list[tuple[str, ...]]) -> str:
    """A loader benchmark as markdown: what was loaded, how, and which of the repeats counts,
    then a table of ``columns`` with a line per row."""
    lines = [
        f"{result['samples']} samples at {result['resolution']} px, batch {result['batch_size']}, "
        f"{result['workers']} loader workers, {which} of {result['repeats']}",
        "",
        "| " + " | ".join(columns) + " |",
        "|" + "---|" * len(columns),
    ]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def loaders_table(result: dict) -> str:
    """:func:`compare_loaders`' result as markdown."""
    rows = [
        (name, f"{result[name]['samples_per_s']:.1f}", f"{result[name]['open_s']:.2f}")
        for name in ("folder", "publication")
    ]
    return _loader_table(result, "best", ("source", "samples/s", "opening (s)"), rows)


def collation_table(result: dict) -> str:
    """:func:`compare_collation`'s result as markdown."""
    rows = [
        (f"{row['machine']}", f"{row['collation']}", f"{row['samples_per_s_median']:.1f}") for row in result["rows"]
    ]
    return _loader_table(result, "median", ("machine", "collation", "samples/s"), rows)


def training_table(result: dict) -> str:
    """:func:`compare_training`'s result as markdown."""
    ratio = next(k for k in result["rows"][0] if k.startswith("ratio_to_"))
    lines = [
        f"{result['resolution']} px, batch {result['batch_size']}, loss {result['loss']}, {result['device']}, "
        f"median of {result['repeats']} x {result['steps']} steps",
        "",
        f"| options | samples/s | {ratio.replace('_', ' ')} | first step (s) |",
        "|---|---|---|---|",
    ]
    for row in result["rows"]:
        lines.append(
            f"| {row['options']} | {row['samples_per_s_median']:.2f} | {row[ratio]:.3f} | {row['first_step_s']:.2f} |"
        )
    return "\n".join(lines) + "\n"
