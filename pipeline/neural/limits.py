"""The neural commands' option ranges and choices, without torch: `cli.py` builds their
--help from these before torch is loaded, and the checks in ``train`` and ``evaluate`` use
the same values (one owner per range)."""

from __future__ import annotations

#: --loss: auto (the default: the paper's l1+vgg where VGG16's ImageNet weights are found, else l1),
#: l1+vgg (the paper's L1 + VGG16 relu3_3 feature loss; refused without the weights) or l1.
LOSS_CHOICES = ("auto", "l1+vgg", "l1", "l2")
#: --width: the fraction of the paper's channels, (0, 1] (1: the paper's network).
WIDTH_RANGE = (0.0, 1.0)
#: --device: where the network runs ("auto": cuda where torch sees a device, else cpu).
DEVICES = ("auto", "cpu", "cuda")
#: train's integer options and their inclusive ranges.
INTEGER_RANGES = {
    "epochs": (1, 100_000),
    "batch_size": (1, 4096),
    "loader_workers": (0, 64),
    "seed": (0, 2**63 - 1),
    "threads": (0, 256),
}
#: torchvision's VGG16 ImageNet weights' file name (torch hub's cache holds it under this name).
VGG16_FILE = "vgg16-397923af.pth"
#: --precision: auto (the default: bf16 on a CPU with bfloat16 instructions, else fp32), fp32, or
#: autocast to bf16 (CPU or CUDA) or fp16 (CUDA, with a gradient scaler).
PRECISIONS = ("auto", "fp32", "bf16", "fp16")
#: evaluate --spp: each low-spp path-tracing rate compared with the network.
SPP_LADDER_RANGE = (1, 4096)
#: Rows of :func:`pipeline.neural.bench.compare_training` (`shaderball neural-bench train-options`): the options each changes from the baseline (the config's:
#: fp32, NCHW, eager and its --threads, unless given otherwise).
TRAINING_VARIANTS = {
    "baseline": {},
    "--channels-last": {"channels_last": True},
    "--precision bf16": {"precision": "bf16"},
    "--precision bf16 --channels-last": {"precision": "bf16", "channels_last": True},
    "--threads 1": {"threads": 1},
    "--threads 2": {"threads": 2},
    "--compile": {"compile": True},
    "--width 0.5": {"width": 0.5},
    "--width 0.25": {"width": 0.25},
}
#: evaluate --split: the run's held-out or training materials, or every sample.
SPLITS = ("test", "train", "all")
#: evaluate --limit: at most the first N samples.
LIMIT_RANGE = (1, 10**9)
#: Counts of `shaderball neural-bench`: passes or rounds, timed steps, spinning processes,
#: samples drawn spread over a dataset (denoise --draws).
REPEATS_RANGE = (1, 1000)
STEPS_RANGE = (1, 10_000)
BUSY_RANGE = (0, 64)
DRAWS_RANGE = (1, 100_000)
#: train --environment-code: numbers in each environment map's learned code (0: none), and the
#: most maps a run gives a code of their own (pipeline.neural.network checks a run's config by them).
ENVIRONMENT_CODE_RANGE = (0, 64)
MAX_ENVIRONMENT_CODES = 4096
