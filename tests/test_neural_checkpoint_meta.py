"""A checkpoint's tensors are checked from their metadata before any is touched
(pipeline.neural.checkpoint_meta): a tensor whose shape and strides describe 1 GiB or 4 TiB
over a storage of a few values, an offset past its storage, a dtype or a name the network
does not have are refused by infer, evaluate, export and a resumed training run, exit 2,
naming the tensor and the file, writing nothing, within a modest memory limit; a good
checkpoint loads as before and gives the same outputs."""

import collections
import io
import os
import resource
import shutil
import subprocess
import sys
import warnings
import zipfile

import pytest
import torch

from pipeline.errors import ShaderballError
from pipeline.neural import checkpoint_meta, runfiles
from pipeline.neural.infer import load_run_model
from support.bombs import PEAK
from support.neural_fakes import TINY, assert_checkpoint_refused

torch.set_num_threads(1)
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: The address space each refused command runs in (torch and the CLI need ~1.5 GiB of it).
LIMIT = 3 << 30
#: The peak resident memory of a refusal: the imports' (~300 MB) and a margin, far below the
#: 256 MiB-1 TiB that reading one of these tensors whole allocates.
PEAK_MB = 600


class Forged:
    """A tensor as torch.save writes it, with the storage, offset, shape and strides given:
    ``torch.save`` pickles what ``__reduce_ex__`` returns, as it does for a tensor."""

    def __init__(self, values: int, offset: int, size, stride, dtype=torch.float32):
        self.storage = torch.zeros(values, dtype=dtype).untyped_storage()
        self.dtype, self.rest = dtype, (offset, tuple(size), tuple(stride))

    def __reduce_ex__(self, protocol):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            typed = torch.TypedStorage(wrap_storage=self.storage, dtype=self.dtype, _internal=True)
        return torch._utils._rebuild_tensor_v2, (typed, *self.rest, False, collections.OrderedDict())


def _trusted(path):
    """The test's own reading of a checkpoint it wrote (not the code under test)."""
    return torch.load(path, map_location="cpu", weights_only=True)


def _name(ckpt, shape_len=2):
    return next(n for n, t in ckpt["model"].items() if t.dim() == shape_len)


def _big_stride_0(ckpt):
    name = _name(ckpt)
    ckpt["model"][name] = Forged(4, 0, (1 << 28,), (0,))  # 1 GiB of float32 over 16 bytes
    return f"size mismatch for model['{name}']: shape (268435456,) in the checkpoint"


def _tib_stride_0(ckpt):
    name = _name(ckpt)
    ckpt["model"][name] = Forged(4, 0, (1 << 20, 1 << 20), (0, 0))  # 4 TiB
    return f"model['{name}']: shape (1048576, 1048576)"


def _grown(ckpt):
    name = _name(ckpt)
    ckpt["model"][name] = Forged(4, 0, (1 << 28,), (1,))  # the storage grown to 1 GiB on reading
    return f"model['{name}']: shape (268435456,)"


def _right_shape_stride_0(ckpt):
    name = _name(ckpt)
    shape = tuple(ckpt["model"][name].shape)
    ckpt["model"][name] = Forged(1, 0, shape, (0,) * len(shape))  # every value the same one
    return f"tensor model['{name}']: strides (0, 0) for shape {shape}: not one dense layout"


def _overlapping(ckpt):
    name = _name(ckpt)
    rows, cols = ckpt["model"][name].shape
    ckpt["model"][name] = Forged(rows * cols, 0, (rows, cols), (1, 1))
    return f"tensor model['{name}']: strides (1, 1) for shape ({rows}, {cols}): not one dense layout"


def _offset_past(ckpt):
    name = _name(ckpt)
    shape = tuple(ckpt["model"][name].shape)
    numel = shape[0] * shape[1]
    ckpt["model"][name] = Forged(numel, 1 << 28, shape, (shape[1], 1))
    return f"tensor model['{name}']: offset 268435456 + {numel} values, past the end of its storage of {numel}"


def _float64(ckpt):
    name = _name(ckpt)
    ckpt["model"][name] = ckpt["model"][name].double()
    return f"tensor model['{name}']: dtype float64, where the network's is float32"


def _half(ckpt):
    name = _name(ckpt, 1)
    ckpt["model"][name] = ckpt["model"][name].half()
    return f"tensor model['{name}']: dtype float16"


def _extra(ckpt):
    ckpt["model"]["extra.weight"] = torch.zeros(3)
    return "weights unexpected extra.weight"


def _missing(ckpt):
    name = _name(ckpt)
    del ckpt["model"][name]
    return f"weights missing {name}"


def _elsewhere(ckpt):
    ckpt["history"][0]["hidden"] = Forged(4, 0, (1 << 28,), (0,))
    return "tensor history[0]['hidden']: a tensor where a checkpoint of this network holds none"


def _optimizer_stride_0(ckpt):
    shape = tuple(ckpt["optimizer"]["state"][0]["exp_avg"].shape)
    ckpt["optimizer"]["state"][0]["exp_avg"] = Forged(1, 0, shape, (0,) * len(shape))
    return "tensor optimizer['state'][0]['exp_avg']: strides"


def _optimizer_big(ckpt):
    ckpt["optimizer"]["state"][0]["exp_avg_sq"] = Forged(4, 0, (1 << 28,), (0,))
    return "size mismatch for optimizer['state'][0]['exp_avg_sq']: shape (268435456,)"


CASES = {
    "1gib-stride-0": _big_stride_0,
    "4tib-stride-0": _tib_stride_0,
    "1gib-grown-storage": _grown,
    "right-shape-stride-0": _right_shape_stride_0,
    "overlapping-strides": _overlapping,
    "offset-past-storage": _offset_past,
    "float64": _float64,
    "float16": _half,
    "extra-tensor": _extra,
    "missing-tensor": _missing,
    "tensor-in-history": _elsewhere,
    "optimizer-stride-0": _optimizer_stride_0,
    "optimizer-1gib": _optimizer_big,
}


def _forge(run, dest, case):
    broken = shutil.copytree(run, dest)
    ckpt = _trusted(broken / "checkpoint.pt")
    words = CASES[case](ckpt)
    torch.save(ckpt, broken / "checkpoint.pt")
    assert (broken / "checkpoint.pt").stat().st_size < 4 << 20
    return broken, words


def _commands(run_dir, reference, out):
    return {
        "infer": ["infer", run_dir, "--out", out / "ball.exr", "--png", out / "ball.png"],
        "evaluate": ["evaluate", run_dir, reference, "--spp", "none", "--out", out / "ev"],
        "export": ["export", run_dir, "--out", out / "net.pt"],
        "resume": ["train", reference, "--out", run_dir, "--epochs", 2, *TINY],
    }


@pytest.mark.slow
@pytest.mark.parametrize("case", list(CASES))
def test_a_forged_tensor_is_refused_by_every_command_naming_it(tiny_run, reference, tmp_path, case):
    broken, words = _forge(tiny_run, tmp_path / "broken", case)
    out = tmp_path / "out"
    assert_checkpoint_refused(broken, out, _commands(broken, reference, out), words)


def _limited():
    resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))


@pytest.mark.slow
@pytest.mark.parametrize("case", ["1gib-stride-0", "4tib-stride-0", "optimizer-1gib"])
def test_a_refusal_stays_within_a_modest_memory_limit(tiny_run, reference, tmp_path, case):
    broken, words = _forge(tiny_run, tmp_path / "broken", case)
    out = tmp_path / "out"
    out.mkdir()
    commands = _commands(broken, reference, out)
    for command in ["resume"] if case.startswith("optimizer") else commands:
        note = tmp_path / f"{command}.peak"
        done = subprocess.run(
            [sys.executable, "-c", PEAK, str(note), *map(str, commands[command])],
            capture_output=True,
            text=True,
            timeout=300,
            cwd=REPO,
            preexec_fn=_limited,
        )
        assert done.returncode == 2, (command, done.returncode, done.stdout, done.stderr[-2000:])
        assert words in done.stdout + done.stderr, (command, done.stdout, done.stderr[-2000:])
        peak = float(note.read_text())
        assert peak < PEAK_MB, (command, peak)
    assert os.listdir(out) == []


def test_the_metadata_is_read_without_torch_load(tiny_run, monkeypatch, tmp_path):
    """The refusal comes from data.pkl alone: torch.load is never reached."""
    broken, words = _forge(tiny_run, tmp_path / "broken", "4tib-stride-0")

    def no_load(*args, **kwargs):
        raise AssertionError("torch.load reached")

    monkeypatch.setattr(torch, "load", no_load)
    with pytest.raises(ShaderballError, match="checkpoint.pt: the weights do not fit the network") as caught:
        runfiles.load_checkpoint(str(broken))
    assert words in str(caught.value)


def test_a_global_no_checkpoint_holds_is_refused_unread(tiny_run, tmp_path, monkeypatch):
    """bytearray(n) allocates n bytes from one integer: torch's reader allows it, this one does not."""

    class Bomb:
        def __reduce__(self):
            return bytearray, (1 << 40,)

    broken = shutil.copytree(tiny_run, tmp_path / "broken")
    ckpt = _trusted(broken / "checkpoint.pt")
    ckpt["history"][0]["x"] = Bomb()
    torch.save(ckpt, broken / "checkpoint.pt")
    monkeypatch.setattr(torch, "load", lambda *a, **k: pytest.fail("torch.load reached"))
    with pytest.raises(ShaderballError, match=r"data.pkl names (__builtin__|builtins).bytearray, which no checkpoint"):
        runfiles.load_checkpoint(str(broken))


def test_a_good_checkpoint_loads_with_the_same_weights_and_outputs(tiny_run):
    path = tiny_run / "checkpoint.pt"
    ckpt = runfiles.load_checkpoint(str(tiny_run))
    trusted = _trusted(path)
    assert ckpt["model"].keys() == trusted["model"].keys()
    for name, tensor in trusted["model"].items():
        assert torch.equal(ckpt["model"][name], tensor) and ckpt["model"][name].dtype == tensor.dtype
    for index, entry in trusted["optimizer"]["state"].items():
        for key, value in entry.items():
            assert torch.equal(ckpt["optimizer"]["state"][index][key], value)
    assert ckpt["history"] == trusted["history"] and ckpt["epoch"] == trusted["epoch"]
    model, _config = load_run_model(str(tiny_run), torch.device("cpu"))
    reference = type(model)(model.resolution, model.width).eval()
    reference.load_state_dict(trusted["model"])
    g = torch.Generator().manual_seed(0)
    maps, light = torch.rand(2, 12, 16, 16, generator=g), torch.rand(2, 4, generator=g)
    with torch.no_grad():
        assert torch.equal(model(maps, light), reference(maps, light))


def test_a_channels_last_checkpoint_is_one_dense_layout(tiny_run, tmp_path):
    """Strides that permute the dimensions (channels-last, as `train --channels-last` saves
    them) describe each value once: accepted."""
    broken = shutil.copytree(tiny_run, tmp_path / "broken")
    ckpt = _trusted(broken / "checkpoint.pt")
    ckpt["model"] = {
        k: v.contiguous(memory_format=torch.channels_last) if v.dim() == 4 else v for k, v in ckpt["model"].items()
    }
    torch.save(ckpt, broken / "checkpoint.pt")
    loaded = runfiles.load_checkpoint(str(broken))
    name = next(k for k, v in loaded["model"].items() if v.dim() == 4 and v.shape[1] > 1 and v.shape[2] > 1)
    assert not loaded["model"][name].is_contiguous() and torch.equal(loaded["model"][name], ckpt["model"][name])


@pytest.mark.parametrize(
    "size, stride, offset, values, ok",
    [
        ((4, 3), (3, 1), 0, 12, True),
        ((4, 3), (1, 4), 0, 12, True),  # column-major
        ((4, 1), (1, 7), 0, 4, True),  # a dimension of 1: any stride
        ((4, 3), (3, 1), 1, 12, False),  # one past the end
        ((4, 3), (3, 1), 1, 13, True),
        ((4, 3), (4, 1), 0, 16, False),  # a gap
        ((4, 3), (2, 1), 0, 12, False),  # overlap
        ((4, 3), (0, 1), 0, 3, False),
        ((), (), 0, 1, True),
        ((), (), 1, 1, False),
    ],
)
def test_layouts(size, stride, offset, values, ok):
    storage = checkpoint_meta.StorageRef("0", torch.float32, values, "cpu")
    tensor = checkpoint_meta.TensorRef((storage, offset, size, stride, False, collections.OrderedDict()))
    assert (checkpoint_meta.layout_problem(tensor) is None) == ok


def _archive(pickled: bytes) -> zipfile.ZipFile:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as out:
        out.writestr("archive/data.pkl", pickled)
    return zipfile.ZipFile(io.BytesIO(buffer.getvalue()))


def test_a_pickle_made_to_exhaust_its_reader_is_read_bounded():
    """The C unpickler's memo is an array that one LONG_BINPUT of index 2**32-1 resizes to
    32 GiB (MemoryError); the reader here keeps a dict. Lists nested 200,000 deep are refused
    by depth, not walked with ever longer paths."""
    root, tensors = checkpoint_meta.read_tensor_refs(_archive(b"\x80\x02]r\xff\xff\xff\xff."))
    assert root == [] and tensors == {}
    deep = 200_000
    pickled = b"\x80\x02}X\x07\x00\x00\x00history" + b"]" * deep + b"a" * (deep - 1) + b"s."
    with pytest.raises(checkpoint_meta.CheckpointRefused, match=r"history\[0\]\[0\]\[0\]...: nested deeper"):
        checkpoint_meta.read_tensor_refs(_archive(pickled))
