"""A trained network exported as TorchScript computes what the model computes,
loaded by torch alone."""

import json
import subprocess
import sys

import pytest
import torch

from pipeline.errors import ShaderballError
from pipeline.neural.config import ExportRequest
from pipeline.neural.export import EXTRA, example_inputs, export_torchscript
from pipeline.neural.infer import load_run_model
from pipeline.neural.train import TrainConfig, train
from support.neural_fakes import FakeSource

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("export") / "run"
    config = TrainConfig(
        dataset="(in memory)", out=str(out), epochs=1, batch_size=2, loss="l1", device="cpu", seed=1, test_fraction=0.25
    )
    train(config, source=FakeSource())
    return out


def test_the_export_gives_the_models_output(run, tmp_path):
    path = tmp_path / "net.pt"
    meta = export_torchscript(ExportRequest(network={"run": str(run), "checkpoint": "best"}, out=str(path)))
    model, _ = load_run_model(str(run), torch.device("cpu"), "best")
    extra = {EXTRA: ""}
    loaded = torch.jit.load(str(path), _extra_files=extra)
    assert json.loads(extra[EXTRA]) == meta and meta["resolution"] == 32
    maps, light = example_inputs(32, batch=3, seed=7)  # not the tracing inputs
    with torch.no_grad():
        expected, got = model(maps, light), loaded(maps, light)
    assert got.shape == (3, 3, 32, 32)
    torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-6)
    assert float((expected - 0.5).abs().max()) > 1e-3  # not a constant picture that any net would match


def test_the_export_loads_in_a_process_without_this_package(run, tmp_path):
    path = tmp_path / "net.pt"
    export_torchscript(ExportRequest(network={"run": str(run)}, out=str(path)))
    code = (
        "import sys, torch; sys.modules['pipeline'] = None; net = torch.jit.load(sys.argv[1]); "
        "print(tuple(net(torch.rand(1, 12, 32, 32), torch.tensor([[0.0, 0.0, 3.0, 3.0]])).shape))"
    )
    done = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "(1, 3, 32, 32)"


def test_bad_names_are_refused(run, tmp_path):
    with pytest.raises(ShaderballError, match="^out: .*net.onnx.* .pt, .pth or .ts"):
        ExportRequest(network={"run": str(run)}, out=str(tmp_path / "net.onnx"))
    with pytest.raises(ShaderballError, match="^checkpoint: .*missing.pt"):
        export_torchscript(
            ExportRequest(
                network={"run": str(run), "checkpoint": str(tmp_path / "missing.pt")}, out=str(tmp_path / "net.pt")
            )
        )
