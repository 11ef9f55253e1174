"""The neural commands' requests, declared once and without torch.

Each command's inputs are the fields of one class here: `shaderball train`'s
:class:`TrainConfig`, `infer`'s :class:`InferRequest`, `evaluate`'s :class:`EvaluateRequest`,
`export`'s :class:`ExportRequest`, `sweep`'s :class:`SweepRequest`, and `neural-bench`'s
:class:`LoadersRequest`, :class:`CollateRequest`, :class:`DenoiseRequest` and
:class:`TrainOptionsRequest`. A field's declaration (``pipeline.fields``) is its default,
range, unit and help; the command line is generated from it (``pipeline.ui.command``) and a
refused value names the field (``epochs: 0 is not allowed; an integer from 1 to 100000``;
the command line spells it ``--epochs``). A parameter several commands take is declared
once and reused (``same_as``): the dataset, the device, the checkpoint, the resolution, the
batch size, the loader workers, the threads, the low-spp ladder, the repeats.

No torch here: the command line builds its --help before torch is loaded; the modules that
do the work (``pipeline.neural.train``, ``.evaluate``, ...) take these requests.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from pipeline.check.request import dataset_operand
from pipeline.fields import Checked, field, part, same_as
from pipeline.fields.rules import (
    Bool,
    Choice,
    Float,
    Int,
    IntList,
    Many,
    Optional,
    Pair,
    Path,
    Reject,
    Rule,
    StrList,
    Text,
    format_value,
)
from pipeline.image.tonemap import DEFAULT_EXPOSURE
from pipeline.neural.limits import (
    BUSY_RANGE,
    DEVICES,
    DRAWS_RANGE,
    ENVIRONMENT_CODE_RANGE,
    INTEGER_RANGES,
    LIMIT_RANGE,
    LOSS_CHOICES,
    PRECISIONS,
    REPEATS_RANGE,
    SPLITS,
    SPP_LADDER_RANGE,
    STEPS_RANGE,
    TRAINING_VARIANTS,
    VGG16_FILE,
    WIDTH_RANGE,
)
from pipeline.neural.runfolder import check_run_folder
from pipeline.publish.request import VerifyRequest
from pipeline.render.command import check_output
from pipeline.render.parts import MaterialPart, SunSkyPart
from pipeline.render.settings import RenderSettings

#: --schedule: constant (after any warm-up), or cosine decay to 0 at the last epoch.
SCHEDULES = ("constant", "cosine")
#: Network resolutions: multiples of this (the encoder halves the image 4 times).
RESOLUTION_MULTIPLE = 16
NETWORK_RESOLUTION_RANGE = (16, 4096)
#: What the dataset operand of the neural commands must be.
A_DATASET = "a dataset folder written by `shaderball build`, or its publication (`shaderball publish`)"


class NetworkResolution(Rule):
    """A resolution the network accepts: a multiple of 16 from 16 to 4096."""

    py_type = int
    allowed = "an integer multiple of 16 from 16 to 4096 (the encoder halves it 4 times)"

    def check(self, value):
        lo, hi = NETWORK_RESOLUTION_RANGE
        if (
            isinstance(value, bool)
            or not isinstance(value, int)
            or not lo <= value <= hi
            or value % RESOLUTION_MULTIPLE
        ):
            raise Reject()
        return value

    @property
    def brief(self) -> str:
        return "a multiple of 16 from 16 to 4096"


class Folder(Path):
    """A folder a command writes into: a new one, or an existing folder (never a file)."""

    def check(self, value):
        value = super().check(value)
        if value and os.path.exists(value) and not os.path.isdir(value):
            raise Reject(what=f"{format_value(value)} is a file")
        return value


class FileName(Path):
    """A file a command writes, whose name ends in one of ``suffixes`` (any case)."""

    def __init__(self, *suffixes: str):
        *first, last = suffixes
        super().__init__("a file name ending in " + (", ".join(first) + " or " if first else "") + last)
        self.suffixes = suffixes

    def check(self, value):
        value = super().check(value)
        if not value.lower().endswith(self.suffixes):
            raise Reject()
        if os.path.isdir(value):
            raise Reject(what=f"{format_value(value)} is a folder")
        return value


class RotationRange(Pair):
    """A range of environment-map rotations in degrees, ``LO,HI`` on a command line."""

    metavar = "LO,HI"

    def __init__(self):
        super().__init__(0.0, 360.0)

    def parse(self, text: str):
        return tuple(float(word) for word in text.split(","))

    @property
    def brief(self) -> str:
        return "LO,HI degrees, 0 <= LO <= HI <= 360"


def _int(name: str) -> Int:
    return Int(*INTEGER_RANGES[name])


@dataclass(frozen=True)
class TrainConfig(Checked):
    """`shaderball train`: a run's every option (a resume must repeat those that change what
    it computes: pipeline.neural.train.IDENTITY_FIELDS)."""

    # empty: no dataset (the training-speed benchmark of synthetic batches); train() refuses it
    dataset: str = field(
        rule=Path("a dataset folder or its publication", empty_ok=True),
        doc="A dataset folder written by `shaderball build`, or its publication (`shaderball publish`).",
        positional=True,
        metavar="DATASET",
    )
    out: str | None = field(
        None,
        rule=Optional(Folder("a run folder"), "unset (only with {benchmark})"),
        doc="Run folder (new, empty, or a run to resume): config.json, log.jsonl, loss.png, checkpoint.pt (weights "
        "and Adam's state, to resume; at 400 px 141 MB with {width} 1, 37 MB with 0.5) and checkpoint-best.pt "
        "(weights only: 47 MB, 12 MB; scripts/checkpoint_sizes.py). [required, except with {benchmark}]",
    )
    epochs: int = field(
        30, rule=_int("epochs"), doc="Epochs to reach; running again with more continues the run.", unit="epochs"
    )
    minutes: float | None = field(
        None,
        rule=Optional(Float(0.0, 1e6, lo_open=True), "unset (no time budget)"),
        doc="Time budget of a new run, from the command's start: after the first epoch (timed with its scoring, "
        "at the full learning rate) the run's length is set to the epochs that fit, at most {epochs}, then "
        "shortened after any epoch that says the rest would not fit, and kept when it resumes; a cosine "
        "{schedule} decays over the epochs after the first [default: none, {epochs} epochs].",
        unit="minutes",
    )
    batch_size: int = field(6, rule=_int("batch_size"), doc="Samples per step (the paper: 6).", unit="samples")
    lr: float = field(
        1e-3,
        rule=Float(0.0, 10.0, lo_open=True),
        doc="Adam learning rate (the released code's; the paper's text: 1e-2, which saturates; docs/neural.md).",
    )
    loss: str = field(
        "auto",
        rule=Choice(LOSS_CHOICES),
        doc="l1+vgg: L1 + VGG16 relu3_3 feature loss (the paper's; refused without VGG16 weights); l1: L1 alone; l2: "
        "mean squared error alone (each on the tone-mapped sRGB targets); "
        "auto: l1+vgg where the weights are found ({vgg_weights} or torch hub's cache), else l1, and says which.",
    )
    vgg_weights: str | None = field(
        None,
        rule=Optional(Path("a file"), "unset (torch hub's cache)"),
        doc="torchvision's vgg16 state dict (vgg16-397923af.pth) [default: torch hub's cache, "
        "$TORCH_HOME/hub/checkpoints/]. Never downloaded.",
        metavar="FILE",
    )
    vgg_sha256: str | None = field(
        None,
        rule=Optional(Text(r"[0-9a-fA-F]{64}", "64 hexadecimal digits"), "unset (torchvision's file)"),
        doc="Expected SHA-256 of {vgg_weights} [default: torchvision's ImageNet file's].",
        metavar="HEX",
    )
    vgg_weight: float = field(1.0, rule=Float(0.0, 1e6), doc="Weight of the VGG term beside L1.")
    device: str = field(
        "auto",
        rule=Choice(DEVICES),
        doc="Where the network runs: auto (cuda when torch sees a GPU, else cpu), cpu or cuda.",
    )
    devices: int = field(
        1,
        rule=Int(1, 64),
        doc="Processes training together, one a device, in DistributedDataParallel (gloo on a CPU, nccl on "
        "CUDA), each taking an equal part of every batch of {batch_size} (docs/neural.md); 1: one process.",
        unit="processes",
        in_file=False,
    )
    loader_workers: int = field(
        0,
        rule=_int("loader_workers"),
        doc="DataLoader worker processes (0: load in the main process).",
        unit="processes",
    )
    seed: int = field(0, rule=_int("seed"), doc="Seeds the weights, the per-epoch order and the split.")
    resolution: int | None = field(
        None,
        rule=Optional(NetworkResolution(), "unset (the dataset's)"),
        doc="Network resolution, dividing the dataset's (images box-averaged) [default: the dataset's].",
        unit="pixels",
    )
    test_fraction: float = field(
        0.2, rule=Float(0.0, 1.0, hi_open=True), doc="Fraction of materials held out for testing."
    )
    split_seed: int | None = field(
        None,
        rule=Optional(_int("seed"), "unset ({seed})"),
        doc="Seeds the split by material (and {train_materials}' choice) apart from {seed}, so runs of "
        "several seeds share one held-out set [default: {seed}].",
    )
    train_materials: int | None = field(
        None,
        rule=Optional(Int(1, 10**9), "unset (all)"),
        doc="Train on this many of the training split's materials (nested: a smaller count takes a subset of a "
        "larger one; the held-out set stays) [default: all].",
        unit="materials",
    )
    held_out_objects: tuple[str, ...] | None = field(
        None,
        rule=Optional(StrList(None, "object names"), "unset (none)"),
        doc="Hold these objects out of training, every material on them under every light (their materials "
        "join the test split; the other objects' materials split by {test_fraction}); an object the dataset "
        "lacks, or all of them, is refused [default: none].",
        metavar="NAME,NAME,...",
    )
    held_out_rotations: tuple[float, float] | None = field(
        None,
        rule=Optional(RotationRange(), "unset (none)"),
        doc="Hold out the environment-lit samples whose map rotation lies in [LO, HI] degrees: the training "
        "materials' samples there join the test split, evaluate reports them apart [default: none].",
        unit="degrees",
    )
    geometry: bool = field(
        False,
        rule=Bool(),
        doc="Give the network the geometry buffers as 4 more input channels (geometry_normal as (n+1)/2, depth "
        "standardised per image over the object; pipeline.neural.scene_inputs); refused on a dataset whose "
        "storage.layers lacks geometry_normal or depth. evaluate and infer feed a run what it trained with.",
    )
    environment_code: int = field(
        0,
        rule=Int(*ENVIRONMENT_CODE_RANGE),
        doc="A learned code of this many numbers per environment map (by its SHA-256) beside the lighting "
        "vector; sun-lit samples and maps the run never saw get a shared code; 0: none.",
        unit="numbers",
    )
    width: float = field(
        1.0,
        rule=Float(*WIDTH_RANGE, lo_open=True),
        doc="Fraction of the paper's channels; 1 is the paper's network, 0.5 about a quarter of its "
        "work for CPU-scale runs (docs/neural.md).",
    )
    schedule: str = field(
        "constant",
        rule=Choice(SCHEDULES),
        doc="Learning rate after the warm-up: constant, or a cosine decay reaching 0 at {epochs} (the run then "
        "ends at {epochs}: a longer run is another configuration).",
    )
    warmup_epochs: float = field(
        0.0,
        rule=Float(0.0, float(INTEGER_RANGES["epochs"][1])),
        doc="Linear warm-up of the learning rate over this many epochs (fractions allowed), 0 to {epochs}.",
        unit="epochs",
    )
    exposure: float = field(
        DEFAULT_EXPOSURE,
        rule=Float(0.0, 1e6, lo_open=True),
        doc="Tone map exposure of the targets (pipeline.image.tonemap).",
    )
    hash_check: bool = field(True, rule=Bool(), doc="Check each file's SHA-256 against the manifest on first read.")
    threads: int = field(
        0,
        rule=_int("threads"),
        doc="torch intra-op threads (0: the cores this process may use: its CPU affinity, at most its cgroup's "
        "CPU quota; docs/neural.md, Speed on a CPU).",
        unit="threads",
    )
    precision: str = field(
        "auto",
        rule=Choice(PRECISIONS),
        doc="auto: bf16 on a CPU with bfloat16 instructions (/proc/cpuinfo's avx512_bf16 or amx_bf16: 1.7x "
        "fp32's speed there, 2.1x with {channels_last}), else fp32 (CUDA too; emulated bf16 ran 5.4x slower "
        "than fp32 on an AVX2 CPU); fp32: the same computation on every CPU; bf16: autocast to bfloat16 (CPU or "
        "CUDA); fp16: autocast to float16 with a gradient scaler (CUDA).",
    )
    channels_last: bool = field(
        True, rule=Bool(), doc="Network, VGG and batches in channels-last (NHWC) memory format."
    )
    compile: bool = field(False, rule=Bool(), doc="torch.compile the network for the training step.")
    benchmark: bool = field(
        False,
        rule=Bool(),
        doc="Measure loader samples/s, training samples/s and inference ms instead of training; writes nothing.",
        in_file=False,
    )

    def check_cross(self) -> None:
        if self.batch_size % self.devices:
            raise self.field_error(
                "batch_size",
                self.batch_size,
                f"a multiple of the {{devices}}, {self.devices} (each process takes an equal part of a batch)",
            )
        if self.devices > 1 and self.benchmark:
            raise self.field_error("devices", self.devices, "1 with {benchmark}")
        if self.devices > 1 and self.minutes is not None:
            raise self.field_error("minutes", self.minutes, "unset with {devices} over 1 (one process times the run)")
        if self.warmup_epochs > self.epochs:
            raise self.field_error(
                "warmup_epochs", self.warmup_epochs, f"a finite number from 0 to {self.epochs:g}, the {{epochs}}"
            )

    def check_run(self, *, dataset_opened: bool = False) -> None:
        """The checks of a run's paths and options that need neither torch nor the data (the command
        line makes them before torch loads): the {out} folder (unless {benchmark}), the dataset
        there (unless ``dataset_opened``: the caller hands the data over), a named VGG16 file, fp16
        on the CPU."""
        if not self.benchmark:
            check_run_folder(TrainConfig, "out", self.out)
        if not dataset_opened and not self.dataset and not self.benchmark:
            raise self.field_error("dataset", self.dataset, A_DATASET, what="missing")
        if not dataset_opened and self.dataset and not os.path.lexists(self.dataset):
            raise self.field_error(
                "dataset", self.dataset, A_DATASET, what=f"{format_value(self.dataset)} does not exist"
            )
        if self.loss not in ("l1", "l2") and self.vgg_weights is not None and not os.path.isfile(self.vgg_weights):
            raise self.field_error(
                "vgg_weights",
                self.vgg_weights,
                f"torchvision's vgg16 state dict ({VGG16_FILE})",
                what=f"{format_value(self.vgg_weights)} is not a file",
            )
        if self.precision == "fp16" and self.device == "cpu":
            raise self.field_error("precision", self.precision, "fp32 or bf16 on a CPU (fp16 autocast is for CUDA)")

    @property
    def splitting_seed(self) -> int:
        return self.seed if self.split_seed is None else self.split_seed


@dataclass(frozen=True)
class NetworkPart(Checked):
    """A trained network: its run folder and which of its checkpoints (infer, evaluate, export)."""

    run: str = field(
        rule=Path("a training run folder", exists="folder"),
        doc="A training run folder (config.json, checkpoint.pt) written by `shaderball train`.",
        positional=True,
        metavar="RUN",
    )
    checkpoint: str = field(
        "last",
        rule=Path("last, best, or a checkpoint file of the run"),
        doc="The last epoch's weights, the best held-out PSNR's (checkpoint-best.pt; chosen on the test split, so "
        "optimistic when evaluated there), or a checkpoint file of {run}.",
        metavar="last|best|FILE",
    )


@dataclass(frozen=True)
class InferRequest(Checked):
    """`shaderball infer`: the network's picture of one material under one sun."""

    network: NetworkPart = part(NetworkPart, doc="The trained network.")
    out: str = field(
        rule=FileName(".exr"),
        doc="Output EXR file: render.R/G/B, the network's estimate in linear HDR (inverse tone map), and the maps.",
    )
    png: str | None = field(
        None, rule=Optional(FileName(".png"), "unset (none)"), doc="Also write the network's picture as PNG."
    )
    material: MaterialPart = part(MaterialPart, doc="The material the network is shown.")
    sun_sky: SunSkyPart = part(SunSkyPart, doc="The sun and sky it is lit by.")
    device: str = same_as(TrainConfig, "device")

    def check_cross(self) -> None:
        check_output(type(self), "out", self.out, ".exr")  # the files' folders writable, as render's
        if self.png is not None:
            check_output(type(self), "png", self.png, ".png")


@dataclass(frozen=True)
class EvaluateRequest(Checked):
    """`shaderball evaluate`: a run's network against a dataset's path-traced references."""

    network: NetworkPart = part(NetworkPart, doc="The trained network.")
    dataset: str = same_as(
        TrainConfig, "dataset", rule=Path("a dataset folder or its publication", exists="any"), positional=True
    )
    reference: str | None = field(
        None,
        rule=Optional(Path("a dataset folder or its publication", exists="any"), "unset ({dataset}'s own renders)"),
        doc="Score against this build's renders of the same samples instead of {dataset}'s: a build of the same "
        "spec but for render.spp (e.g. a high-spp rebuild), so a network trained on noisy renders is scored "
        "against clean ones.",
        metavar="DIR|PUB",
    )
    split: str = field(
        "test",
        rule=Choice(SPLITS),
        doc="The run's held-out (test) or training materials ({dataset} must hold the files the run was trained "
        "on), or all samples.",
    )
    out: str | None = field(
        None,
        rule=Optional(Folder("a folder"), "unset ({run}/evaluation-<split>)", default_text="{run}/evaluation-<split>"),
        doc="The one folder of the evaluation: results.json, results.md, grid.png (maps, reference, network, path "
        "tracing at equal time and 2 spp, denoised, error maps), and with {report} the report.",
    )
    overwrite: bool = field(
        False,
        rule=Bool(),
        doc="Replace an earlier evaluation in the {out} folder (its results, grid and report files); without it, "
        "a folder that holds one is refused before anything runs.",
    )
    json_out: str | None = field(
        None,
        rule=Optional(FileName(".json"), "unset (none)"),
        doc="Also write the results (per sample and mean) to this JSON file.",
        metavar="FILE",
    )
    spp: tuple[int, ...] = field(
        (1, 2, 4, 16),
        rule=IntList(*SPP_LADDER_RANGE, none="none"),
        doc="Low-spp path tracing to compare with, in samples per pixel; none: no path tracing.",
    )
    denoise: bool = field(True, rule=Bool(), doc="Denoise each low-spp render with Intel OIDN (a row of its own).")
    limit: int | None = field(
        None,
        rule=Optional(Int(*LIMIT_RANGE), "unset (all)", default_text="all"),
        doc="Evaluate at most the first N samples of the split (in manifest order).",
        unit="samples",
        metavar="N",
    )
    device: str = same_as(TrainConfig, "device")
    report: bool = field(
        False,
        rule=Bool(),
        doc="Also write, into the {out} folder: report.md (the table, per material class with 95% intervals, "
        "the grid), report.json, learning-curve.png/.csv (training and held-out loss and PSNR per epoch).",
    )
    flip: bool = field(True, rule=Bool(), doc="HDR-FLIP, the slowest metric (most of an evaluation's time at 64x64).")
    hash_check: bool = same_as(TrainConfig, "hash_check")

    @property
    def folder(self) -> str:
        """The folder the evaluation writes: ``out``, else the run's ``evaluation-<split>``."""
        return self.out or os.path.join(self.network.run, f"evaluation-{self.split}")


@dataclass(frozen=True)
class ExportRequest(Checked):
    """`shaderball export`: a run's network as a TorchScript file."""

    network: NetworkPart = part(NetworkPart, doc="The trained network.")
    out: str = field(rule=FileName(".pt", ".pth", ".ts"), doc="TorchScript file to write (.pt, .pth or .ts).")


@dataclass(frozen=True)
class SweepRequest(Checked):
    """`shaderball sweep`: runs of several training-set sizes and seeds side by side."""

    reports: tuple[str, ...] = field(
        rule=Many(Path("a report.json of `shaderball evaluate --report`", exists="file")),
        doc="The report.json `shaderball evaluate --report` wrote for each run.",
        positional=True,
        metavar="REPORT.json",
    )
    out: str = field(rule=Folder("a folder"), doc="Folder for sweep.md, sweep.json and data-size.png.")


@dataclass(frozen=True)
class LoadersRequest(Checked):
    """`shaderball neural-bench loaders`: the loader on a dataset folder and on its publication."""

    folder: str = dataset_operand(exists="folder")
    pub: str = same_as(VerifyRequest, "pub", positional=True)
    resolution: int | None = same_as(TrainConfig, "resolution")
    batch_size: int = same_as(TrainConfig, "batch_size")
    loader_workers: int = same_as(TrainConfig, "loader_workers")
    repeats: int = field(3, rule=Int(*REPEATS_RANGE), doc="Passes over each; the best counts.", unit="passes")
    hash_check: bool = same_as(TrainConfig, "hash_check")


@dataclass(frozen=True)
class CollateRequest(Checked):
    """`shaderball neural-bench collate`: torch's collation against the loader's, idle and loaded."""

    dataset: str = same_as(EvaluateRequest, "dataset", positional=True)
    busy: int = field(2, rule=Int(*BUSY_RANGE), doc="Spinning processes beside the loaded passes.", unit="processes")
    repeats: int = same_as(LoadersRequest, "repeats", default=5, doc="Rounds of passes; medians count.", unit="rounds")
    batch_size: int = same_as(TrainConfig, "batch_size")
    loader_workers: int = same_as(TrainConfig, "loader_workers")
    resolution: int | None = same_as(TrainConfig, "resolution")


@dataclass(frozen=True)
class DenoiseRequest(Checked):
    """`shaderball neural-bench denoise`: what OIDN is fed, against fresh high-spp renders."""

    dataset: str = same_as(EvaluateRequest, "dataset", positional=True)
    draws: int = field(
        12, rule=Int(*DRAWS_RANGE), doc="Samples compared, drawn spread over the dataset.", unit="samples"
    )
    spp: tuple[int, ...] = same_as(
        EvaluateRequest,
        "spp",
        rule=IntList(*SPP_LADDER_RANGE),
        default=(1, 4, 16),
        doc="Path-tracing rates denoised, in samples per pixel.",
    )
    reference_spp: int = same_as(RenderSettings, "spp", default=256, doc="Samples per pixel of the reference renders.")


@dataclass(frozen=True)
class TrainOptionsRequest(Checked):
    """`shaderball neural-bench train-options`: training samples/s of each speed option."""

    resolution: int = same_as(
        TrainConfig, "resolution", rule=NetworkResolution(), default=64, doc="Network resolution."
    )
    batch_size: int = same_as(TrainConfig, "batch_size")
    loss: str = same_as(
        TrainConfig,
        "loss",
        default="l1+vgg",
        doc="l1+vgg: L1 + VGG16 relu3_3 feature loss (a randomly initialised VGG16: the rate does not depend on its "
        "weights); l1: L1 alone; auto: l1.",
    )
    repeats: int = same_as(
        LoadersRequest, "repeats", default=5, doc="Rounds of timed steps; medians count.", unit="rounds"
    )
    steps: int = field(3, rule=Int(*STEPS_RANGE), doc="Steps timed per variant and round.", unit="steps")
    threads: int = same_as(TrainConfig, "threads")
    variants: tuple[str, ...] | None = field(
        None,
        rule=Optional(StrList(tuple(TRAINING_VARIANTS), "speed options"), "unset (all)", default_text="all"),
        doc="Speed options compared, comma-separated, the first the baseline (the options each changes from "
        "the baseline's: fp32, NCHW, eager, its {threads}).",
        metavar="NAME,NAME,...",
    )

    def config(self) -> TrainConfig:
        """The baseline's training options: these, on the CPU, in fp32 and NCHW."""
        return TrainConfig(
            dataset="",
            batch_size=self.batch_size,
            loss=self.loss,
            device="cpu",
            threads=self.threads,
            precision="fp32",
            channels_last=False,
        )
