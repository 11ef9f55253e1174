"""`shaderball train` refuses a bad path or option before torch is imported or any data is read:
the refusal counts no `torch` module loaded (not a time); thread counts say their unit."""

import dataclasses
import os
import subprocess
import sys

import pytest

from pipeline.fields import declared
from pipeline.neural import config as neural_config

# Runs the command line as `shaderball` does, and says on stderr whether torch was imported.
WRAPPER = (
    "import atexit, sys\n"
    "atexit.register(lambda: sys.stderr.write('\\ntorch imported: %s\\n' % ('torch' in sys.modules)))\n"
    "import cli\n"
    "cli.main()\n"
)


def _train(*args):
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ, PYTHONPATH=os.environ.get("PYTHONPATH") or repo)
    cmd = [sys.executable, "-c", WRAPPER, "train", *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=repo)


def _refusals(tmp_path):
    a_file = tmp_path / "a-file"
    a_file.write_text("x")
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("x")
    data = tmp_path / "data"
    data.mkdir()  # exists: the refusal is of another option
    return [
        (["/nonexistent-dataset", "--out", tmp_path / "r"], "DATASET:", "does not exist"),
        ([data, "--out", a_file], "--out:", "is a file"),
        ([data, "--out", other], "--out:", "holds other files"),
        ([data], "--out:", "missing"),
        (
            [data, "--out", tmp_path / "r", "--loss", "l1+vgg", "--vgg-weights", tmp_path / "no.pth"],
            "--vgg-weights:",
            "no.pth",
        ),
        ([data, "--out", tmp_path / "r", "--device", "cpu", "--precision", "fp16"], "--precision:", "fp16"),
        ([data, "--out", tmp_path / "r", "--epochs", "0"], "--epochs:", "0"),
    ]


@pytest.mark.parametrize("case", range(7))
def test_train_refuses_a_bad_path_or_option_before_torch_is_imported(tmp_path, case):
    args, option, named = _refusals(tmp_path)[case]
    before = sorted(os.listdir(tmp_path))
    result = _train(*args)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 2, result.stderr
    assert lines[0].startswith("error: " + option) and named in lines[0], result.stderr
    assert lines[-1] == "torch imported: False", result.stderr
    assert sorted(os.listdir(tmp_path)) == before  # nothing written


def test_thread_and_process_counts_say_their_unit():
    requests = [c for c in vars(neural_config).values() if dataclasses.is_dataclass(c) and isinstance(c, type)]
    counts = [
        (cls.__name__, name, f.metadata["unit"])
        for cls in requests
        for name, f in declared(cls).items()
        if name in ("threads", "devices") or name.endswith("workers")
    ]
    assert ("TrainConfig", "threads", "threads") in counts
    assert all(unit for _cls, _name, unit in counts), counts
