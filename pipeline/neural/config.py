"""`shaderball train`'s options, declared once: :class:`TrainConfig`.

Each field's declaration (``pipeline.fields``) is its default, range, unit and help; the
command's options are generated from it (``pipeline.ui.options``) and a refusal names the
option (``--epochs: 0 is not allowed; an integer from 1 to 100000``). No torch here: the
command builds its --help before torch is loaded.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from pipeline.fields import Bool, Checked, Choice, Float, Int, Optional, Path, Reject, Rule, Text, field
from pipeline.image.tonemap import DEFAULT_EXPOSURE
from pipeline.neural.limits import DEVICES, INTEGER_RANGES, LOSS_CHOICES, PRECISIONS, WIDTH_RANGE

#: --schedule: constant (after any warm-up), or cosine decay to 0 at the last epoch.
SCHEDULES = ("constant", "cosine")
#: Network resolutions: multiples of this (the encoder halves the image 4 times).
RESOLUTION_MULTIPLE = 16
NETWORK_RESOLUTION_RANGE = (16, 4096)


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


def _int(name: str) -> Int:
    return Int(*INTEGER_RANGES[name])


@dataclass
class TrainConfig(Checked):
    """Options of `shaderball train`."""

    FIELD_PREFIX: ClassVar[str] = "--"

    # empty: no dataset (the training-speed benchmark of synthetic batches); train() refuses it
    dataset: str = field(
        rule=Path("a dataset folder or its publication", empty_ok=True), doc="Dataset folder written by `build`."
    )
    out: str = field(
        rule=Path("a run folder", empty_ok=True),
        doc="Run folder: config.json, log.jsonl, log.csv, checkpoint.pt, checkpoint-best.pt, loss.png.",
    )
    epochs: int = field(
        30, rule=_int("epochs"), doc="Epochs to reach; running again with more continues the run.", unit="epochs"
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
        doc="l1+vgg: L1 + VGG16 relu3_3 feature loss (the paper's; refused without VGG16 weights); l1: L1 alone; "
        "auto: l1+vgg where the weights are found (--vgg-weights or torch hub's cache), else l1, and says which.",
    )
    vgg_weights: str | None = field(
        None,
        rule=Optional(Path("a file"), "unset (torch hub's cache)"),
        doc="torchvision's vgg16 state dict (vgg16-397923af.pth) [default: torch hub's cache, "
        "$TORCH_HOME/hub/checkpoints/]. Never downloaded.",
    )
    vgg_sha256: str | None = field(
        None,
        rule=Optional(Text(r"[0-9a-fA-F]{64}", "64 hexadecimal digits"), "unset (torchvision's file)"),
        doc="Expected SHA-256 of --vgg-weights [default: torchvision's ImageNet file's].",
    )
    vgg_weight: float = field(1.0, rule=Float(0.0, 1e6), doc="Weight of the VGG term beside L1.")
    device: str = field("auto", rule=Choice(DEVICES), doc="Where the network runs; auto: cuda when torch sees a GPU.")
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
    exposure: float = field(
        DEFAULT_EXPOSURE,
        rule=Float(0.0, 1e6, lo_open=True),
        doc="Tone map exposure of the targets (pipeline.image.tonemap).",
    )
    check_hashes: bool = field(True, rule=Bool(), doc="Check each file's SHA-256 against the manifest on first read.")
    threads: int = field(
        0,
        rule=_int("threads"),
        doc="torch intra-op threads (0: torch's default, the core count; docs/neural.md, Speed on a CPU).",
    )
    precision: str = field(
        "fp32",
        rule=Choice(PRECISIONS),
        doc="fp32: the same computation on every CPU; bf16: autocast to bfloat16 (CPU or CUDA; 1.7x here, "
        "2.1x with --channels-last); auto: bf16 on a CPU with bfloat16 kernels, else fp32; "
        "fp16: autocast to float16 with a gradient scaler (CUDA).",
    )
    channels_last: bool = field(
        True, rule=Bool(), doc="Network, VGG and batches in channels-last (NHWC) memory format."
    )
    compile: bool = field(False, rule=Bool(), doc="torch.compile the network for the training step.")
    width: float = field(
        1.0,
        rule=Float(*WIDTH_RANGE, lo_open=True),
        doc="Fraction of the paper's channels; 1 is the paper's network, 0.5 about a quarter of its "
        "work for CPU-scale runs (docs/neural.md).",
    )
    split_seed: int | None = field(
        None,
        rule=Optional(_int("seed"), "unset (--seed)"),
        doc="Seeds the split by material (and --train-materials' choice) apart from --seed, so runs of "
        "several seeds share one held-out set [default: --seed].",
    )
    train_materials: int | None = field(
        None,
        rule=Optional(Int(1, 10**9), "unset (all)"),
        doc="Train on this many of the training split's materials (nested: a smaller count takes a subset of a "
        "larger one; the held-out set stays) [default: all].",
        unit="materials",
    )
    schedule: str = field(
        "constant",
        rule=Choice(SCHEDULES),
        doc="Learning rate after the warm-up: constant, or a cosine decay reaching 0 at --epochs (the run then "
        "ends at --epochs: a longer run is another configuration).",
    )
    warmup_epochs: float = field(
        0.0,
        rule=Float(0.0, float(INTEGER_RANGES["epochs"][1])),
        doc="Linear warm-up of the learning rate over this many epochs (fractions allowed), 0 to --epochs.",
        unit="epochs",
    )

    def check(self) -> TrainConfig:
        """Check every field by its declaration, then the rules between fields; return self."""
        return self.check_fields()

    def check_cross(self) -> None:
        if self.warmup_epochs > self.epochs:
            raise self.field_error("warmup_epochs", self.warmup_epochs, f"a finite number from 0 to {self.epochs:g}")

    @property
    def splitting_seed(self) -> int:
        return self.seed if self.split_seed is None else self.split_seed
