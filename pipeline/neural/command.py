"""The neural stage's commands: one function each, which takes the command's request and
returns what the command prints (``lines()``, and ``to_dict()`` for --json).

Importing this module loads no torch (the command line imports it at start, and refuses a
neural command before its body runs where torch is not installed): each function imports
the modules it runs when it is called, after the request's own checks that need no torch.
"""

from __future__ import annotations

from pipeline.errors import NEEDS_TORCH, Printed, ShaderballError
from pipeline.neural.config import (
    CollateRequest,
    DenoiseRequest,
    EvaluateRequest,
    ExportRequest,
    InferRequest,
    LoadersRequest,
    SweepRequest,
    TrainConfig,
    TrainOptionsRequest,
)


def train_command(request: TrainConfig, *, progress=None):
    """`shaderball train`: the run's summary, or with ``request.benchmark`` the benchmark's.
    The run's paths and options are refused before torch loads (seconds) or any data is read."""
    request.check_run()
    if request.benchmark:
        from pipeline.neural.bench import benchmark

        return benchmark(request)
    from pipeline.neural.train import train

    return train(request, progress=progress)


def infer_command(request: InferRequest):
    """`shaderball infer`: the network's picture, written."""
    from pipeline.neural.infer import infer_to_files

    return infer_to_files(request)


def evaluate_command(request: EvaluateRequest, *, progress=None, command: str | None = None):
    """`shaderball evaluate`: the summary (``command``: the report's heading)."""
    from pipeline.neural.evaluate import evaluate

    return evaluate(request, progress=progress, command=command)


def export_command(request: ExportRequest) -> Printed:
    """`shaderball export`: what the TorchScript file's extra shaderball.json holds, and its path."""
    from pipeline.neural.export import export_torchscript

    meta = export_torchscript(request)
    side = meta["resolution"]
    text = f"wrote {request.out}: TorchScript, {side}x{side}, {request.network.checkpoint} checkpoint"
    return Printed({"out": request.out, **meta}, text)


def sweep_command(request: SweepRequest, *, command: str | None = None) -> Printed:
    """`shaderball sweep`: the summary (what sweep.json holds) and its table (``command``: sweep.md's heading)."""
    from pipeline.neural.sweep import write_sweep

    return Printed(*write_sweep(request, command=command))


def bench_command(
    request: LoadersRequest | CollateRequest | DenoiseRequest | TrainOptionsRequest, *, progress=None
) -> Printed:
    """`shaderball neural-bench KIND`: every figure of the kind the request asks for, and their table."""
    from pipeline.neural import bench

    measure, table = {
        LoadersRequest: (bench.compare_loaders, bench.loaders_table),
        CollateRequest: (bench.compare_collation, bench.collation_table),
        DenoiseRequest: (bench.compare_denoisers, bench.denoise_table),
        TrainOptionsRequest: (bench.compare_training, bench.training_table),
    }[type(request)]
    result = measure(request, progress=progress)
    return Printed(result, table(result))


def live_network(options):
    """The network of ``options.run`` for `shaderball serve` (a pipeline.serve.ServeOptions),
    loaded (torch is imported here, when there is a run to serve)."""
    from pipeline.neural.live import LiveNetwork

    return LiveNetwork(options.run, checkpoint=options.checkpoint, threads=options.threads)


def stored_renders(root: str):
    """The stored renders of the dataset ``root`` for `shaderball serve` (torch is imported at
    the first dataset sample shown: serving needs none without it)."""
    try:
        from pipeline.neural.stored import stored_renders as opened
    except ModuleNotFoundError as exc:
        if exc.name != "torch":
            raise
        raise ShaderballError(NEEDS_TORCH) from None
    return opened(root)
