"""The neural stage treats data and run folders as untrusted input: the loader refuses the
samples validate refuses (training stops naming the file), a run that diverges stops
without saving NaN weights, infer and evaluate never write NaN output, and a hostile
config.json or checkpoint is refused naming the field, before anything is decompressed."""

import io
import json
import os
import shutil
import struct
import zipfile

import numpy as np
import OpenEXR
import pytest
import torch
from click.testing import CliRunner

from cli import main
from pipeline.errors import ShaderballError
from pipeline.neural import run_checks, runfiles
from pipeline.neural.network import NeuralRenderer
from pipeline.neural.train import train
from pipeline.neural.train_summary import Diverged
from pipeline.store.exr import encode_exr, read_exr
from support.neural_fakes import TINY, FakeSource, train_config
from support.publishing import rerecord

torch.set_num_threads(1)
RENDER = "shards/s00000/m000000_l0.render.exr"
MAPS = "shards/s00000/m000000.maps.exr"


def _invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _exr(channels: dict, meta: dict, tiled: bool = False) -> bytes:
    """EXR bytes of ``channels`` as OpenEXR writes them (scanline, or tiled)."""
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "shaderball": json.dumps(meta)}
    header["type"] = OpenEXR.tiledimage if tiled else OpenEXR.scanlineimage
    if tiled:
        header["tiles"] = OpenEXR.TileDescription()
    buffer = io.BytesIO()
    OpenEXR.File(header, channels).write(buffer)
    return buffer.getvalue()


def _render_channels(render: np.ndarray, dtype=np.float32) -> dict:
    return {f"render.{c}": np.ascontiguousarray(render[..., i].astype(dtype)) for i, c in enumerate("RGB")}


def _maps_with(data: bytes, edit) -> bytes:
    image = read_exr(data)
    layers = {name: array.copy() for name, array in image.layers.items()}
    edit(layers)
    return encode_exr(layers, image.meta, half=tuple(n for n in layers if n != "mask"))


def _nan_maps(data):
    return _maps_with(data, lambda layers: layers["diffuse"].__setitem__((10, 10, 0), np.nan))


def _rough_maps(data):
    return _maps_with(data, lambda layers: layers["roughness"].__setitem__((0, 0, 0), 1.5))


def _nan_render(data):
    image = read_exr(data)
    render = image.layers["render"].copy()
    render[3, 4, 1] = np.nan
    return encode_exr({"render": render}, image.meta)


def _uint32_render(data):
    image = read_exr(data)
    return _exr(_render_channels(image.layers["render"] * 100, np.uint32), image.meta)


def _many_channels(data):
    image = read_exr(data)
    channels = _render_channels(image.layers["render"])
    zeros = np.zeros(image.layers["render"].shape[:2], np.float32)
    channels.update({f"extra.{i:04d}": zeros for i in range(1997)})
    return _exr(channels, image.meta)


def _tiled(data):
    image = read_exr(data)
    return _exr(_render_channels(image.layers["render"]), image.meta, tiled=True)


def _inverted_window(data):
    """The render's dataWindow patched to end before it starts (x_max < x_min)."""
    key = b"dataWindow\0box2i\0" + struct.pack("<i", 16)
    at = data.index(key) + len(key)
    x_min, y_min, _x_max, y_max = struct.unpack("<4i", data[at : at + 16])
    return data[:at] + struct.pack("<4i", x_min, y_min, x_min - 5, y_max) + data[at + 16 :]


#: (name, file, forgery, words the refusal holds, whether today's validate reports the file)
CASES = [
    ("nan-maps", MAPS, _nan_maps, "layer diffuse has 1 NaN", True),
    ("out-of-range-maps", MAPS, _rough_maps, "layer roughness has 1 value(s) outside [0, 1]", True),
    ("nan-render", RENDER, _nan_render, "1 NaN and 0 infinite value(s)", True),
    ("uint32-render", RENDER, _uint32_render, "layer render is uint32, expected float32", True),
    ("2000-channels", RENDER, _many_channels, "more than 64 channels", True),
    ("tiled", RENDER, _tiled, "not tiled, deep or multi-part", True),
    ("inverted-data-window", RENDER, _inverted_window, "data window is -4 x", True),
]


@pytest.fixture(scope="module")
def forged(reference, tmp_path_factory):
    """A copy of the smoke dataset per case, one file forged and every checksum made to agree."""
    base = tmp_path_factory.mktemp("forged")
    out = {}
    for name, rel, forge, _words, _validated in CASES:
        folder = base / name
        shutil.copytree(reference, folder)
        rerecord(folder, rel, forge((folder / rel).read_bytes()))
        out[name] = folder
    return out


@pytest.mark.parametrize("name, rel, words, validated", [c[:2] + c[3:] for c in CASES], ids=[c[0] for c in CASES])
def test_train_on_a_sample_validate_refuses_exits_2_naming_it_and_writes_nothing(
    forged, tmp_path, name, rel, words, validated
):
    out = tmp_path / "run"
    result = _invoke("train", forged[name], "--out", out, "--epochs", 1, *TINY)
    assert result.exit_code == 2, result.output
    # the file named first (not the command's dataset: a loader's worker may have raised it)
    assert "error: " in result.output and rel in result.output and words in result.output, result.output
    assert "Traceback" not in result.output
    assert not out.exists()
    if validated:  # the same file is what validate reports (a tiled file: the bounded EXR reader's)
        report = _invoke("validate", forged[name], "--json")
        assert report.exit_code != 0 and rel in json.dumps(json.loads(report.stdout)["problems"]), report.output


def test_a_worker_process_that_meets_it_gives_the_same_one_line(forged, tmp_path):
    result = _invoke(
        "train", forged["nan-maps"], "--out", tmp_path / "run", "--epochs", 1, "--loader-workers", 1, *TINY
    )
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and lines[0].startswith(f"error: {forged['nan-maps'] / MAPS}: layer diffuse")
    assert "Traceback" not in result.output and "worker" not in result.output


# --------------------------------------------------------------------------- divergence


class _Poisoned(FakeSource):
    """A FakeSource (it bypasses the loader's checks) with one NaN in one target."""

    def __init__(self):
        super().__init__()
        self.items[0]["target"][0, 1, 1] = float("nan")


def test_a_run_whose_loss_turns_nan_stops_saying_so_and_saves_nothing(tmp_path):
    with pytest.raises(Diverged, match=r"epoch 1: batch \d+ of \d+: the training loss is nan") as caught:
        train(train_config(tmp_path, epochs=2, test_fraction=0.0, lr=2e-3), source=_Poisoned())
    assert "smaller --lr (e.g. --lr 0.0002" in str(caught.value) and caught.value.exit_code == 2
    assert not os.path.exists(tmp_path / "run" / runfiles.CHECKPOINT)
    assert not os.path.exists(tmp_path / "run" / runfiles.BEST_CHECKPOINT)


def test_a_resumed_run_that_diverges_keeps_the_last_finite_checkpoint(tmp_path):
    train(train_config(tmp_path, epochs=1, test_fraction=0.0), source=FakeSource())
    before = (tmp_path / "run" / runfiles.CHECKPOINT).read_bytes()
    with pytest.raises(Diverged, match=r"epoch 2: .*checkpoint.pt keeps epoch 1"):
        train(train_config(tmp_path, epochs=2, test_fraction=0.0), source=_Poisoned())
    assert (tmp_path / "run" / runfiles.CHECKPOINT).read_bytes() == before
    assert run_checks.nonfinite_weights(runfiles.load_checkpoint(str(tmp_path / "run"))["model"]) == 0


# --------------------------------------------------------------------------- run folders


def _copy_run(run, dest):
    shutil.copytree(run, dest)
    return dest


def _commands(run_dir, reference, tmp_path):
    """infer, evaluate and a training resume of ``run_dir``, each with nothing else wrong."""
    return {
        "infer": ["infer", run_dir, "--out", tmp_path / "ball.exr"],
        "evaluate": ["evaluate", run_dir, reference, "--spp", "none", "--out", tmp_path / "ev"],
        "resume": ["train", reference, "--out", run_dir, "--epochs", 2, *TINY],
    }


NEST = "nested 100,000 deep"


def _nest(config):
    config["network"] = NEST  # written as [[[...]]], 100,000 deep (too deep for json.dumps)


CONFIG_CASES = {
    "no-identity-digest": (lambda c: c.pop("identity_digest"), "no identity_digest"),
    "no-network": (lambda c: c.pop("network"), "no network"),
    "network-an-int": (lambda c: c.update(network=5), "network is an integer (5), not an object"),
    "width-a-string": (lambda c: c["network"].update(width="wide"), 'network.width is a string ("wide"), not'),
    "resolution-a-list": (lambda c: c["network"].update(resolution=[16]), "network.resolution is an array ([16])"),
    "resolution-17": (lambda c: c["network"].update(resolution=17), "network.resolution: 17 is not allowed"),
    "identity-a-string": (lambda c: c.update(identity="me"), 'identity is a string ("me"), not an object'),
    "split-train-an-int": (lambda c: c["split"].update(train=3), "split.train is an integer (3), not an array"),
    "split-of-numbers": (lambda c: c["split"].update(test=[1]), "split.test holds an integer (1)"),
    "exposure-negative": (lambda c: c["tonemap"].update(exposure=-1), "tonemap.exposure is -1"),
    "nested-100k-deep": (_nest, "JSON arrays/objects"),
    "options-a-list": (lambda c: c.update(options=[]), "options is an array ([]), not an object"),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", list(CONFIG_CASES))
def test_a_hostile_config_is_refused_naming_the_field(tiny_run, reference, tmp_path, case):
    edit, words = CONFIG_CASES[case]
    broken = _copy_run(tiny_run, tmp_path / "broken")
    config = json.loads((broken / "config.json").read_text())
    edit(config)
    text = json.dumps(config).replace(json.dumps(NEST), "[" * 100_000 + "]" * 100_000)
    (broken / "config.json").write_text(text)
    before = {p.name: p.read_bytes() for p in broken.iterdir()}
    for command, args in _commands(broken, reference, tmp_path).items():
        result = _invoke(*args)
        assert result.exit_code == 2, (command, result.output)
        assert "config.json: " in result.output and words in result.output, (command, result.output)
        assert "Traceback" not in result.output
    assert {p.name: p.read_bytes() for p in broken.iterdir()} == before
    assert sorted(os.listdir(tmp_path)) == ["broken"]


@pytest.mark.slow
def test_a_hostile_log_is_refused_naming_its_line(tiny_run, reference, tmp_path):
    broken = _copy_run(tiny_run, tmp_path / "broken")
    log = broken / "log.jsonl"
    log.write_text(log.read_text() + "[" * 100_000 + "]" * 100_000 + "\n")
    args = ["evaluate", broken, reference, "--spp", "none", "--out", tmp_path / "ev", "--report"]
    result = _invoke(*args)
    assert result.exit_code == 2 and "log.jsonl line 2: not a run's log (100000 JSON arrays" in result.output
    assert "Traceback" not in result.output and sorted(os.listdir(tmp_path)) == ["broken"]
    log.write_text('{"epoch": "one", "train_loss": 0.1}\n')
    result = _invoke(*args)
    assert (
        result.exit_code == 2
        and 'line 1: not a run\'s log (epoch is a string ("one"), not an integer from 1 to 100000)' in result.output
    )


def _zip_bomb(checkpoint: bytes, zeros: int) -> bytes:
    """The checkpoint's members DEFLATE-compressed, one of them ``zeros`` zero bytes long."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(checkpoint)) as src, zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as out:
        for info in src.infolist():
            data = src.read(info)
            if info.filename.endswith("/data/0"):
                data = bytes(zeros)
            out.writestr(info.filename, data)
    return buffer.getvalue()


@pytest.mark.slow
def test_a_compressed_checkpoint_is_refused_before_torch_load_reads_it(tiny_run, tmp_path, monkeypatch):
    bomb = tmp_path / "bomb.pt"
    bomb.write_bytes(_zip_bomb((tiny_run / "checkpoint.pt").read_bytes(), 200 << 20))
    assert bomb.stat().st_size * 50 < 200 << 20  # it would expand 50-fold and more

    def no_load(*args, **kwargs):
        raise AssertionError("torch.load reached")

    monkeypatch.setattr(torch, "load", no_load)
    with pytest.raises(ShaderballError, match=r"bomb.pt: a corrupt checkpoint, member .* is compressed"):
        runfiles.load_checkpoint(str(tiny_run), checkpoint=str(bomb), parameters=40_000)
    monkeypatch.undo()
    result = _invoke("infer", tiny_run, "--out", tmp_path / "x.exr", "--checkpoint", bomb)
    assert result.exit_code == 2 and "torch.save stores its members uncompressed" in result.output, result.output
    assert "remove it" not in result.output and "name a checkpoint this run's configuration wrote" in result.output
    assert not (tmp_path / "x.exr").exists()


def test_a_checkpoint_over_the_budget_of_its_network_is_refused_unread(tmp_path):
    big = tmp_path / "big.pt"
    with zipfile.ZipFile(big, "w", zipfile.ZIP_STORED) as out:
        out.writestr("archive/data/0", bytes(run_checks.checkpoint_budget(1000) + 1))
    with pytest.raises(ShaderballError, match=r"big.pt: a corrupt checkpoint, \d+ bytes, over the \d+ a checkpoint of"):
        runfiles.load_checkpoint(str(tmp_path), checkpoint=str(big), parameters=1000)


@pytest.mark.slow
def test_weights_that_do_not_fit_get_the_whole_message_right_for_the_case(tiny_run, reference, tmp_path):
    broken = _copy_run(tiny_run, tmp_path / "broken")
    ckpt = runfiles.load_checkpoint(str(broken))
    other = NeuralRenderer(16, 0.2).state_dict()  # the run's network is of width 0.1
    state = {k: ckpt[k] for k in ("epoch", "history", "identity_digest")}
    runfiles.save_checkpoint(str(broken), model_state=other, optimizer_state=ckpt["optimizer"], **state)
    own = _invoke("infer", broken, "--out", tmp_path / "x.exr")
    assert own.exit_code == 2, own.output
    assert "the weights do not fit the network (size mismatch for model['" in own.output, own.output
    assert "in the checkpoint" in own.output and "remove it to train again" in own.output
    elsewhere = tmp_path / "mine.pt"
    shutil.copy(broken / "checkpoint.pt", elsewhere)
    given = _invoke("evaluate", broken, reference, "--spp", "none", "--checkpoint", elsewhere, "--out", tmp_path / "e")
    assert given.exit_code == 2 and "size mismatch for" in given.output, given.output
    assert "remove it" not in given.output and "not a checkpoint of the network" in given.output
    resumed = _invoke("train", reference, "--out", broken, "--epochs", 2, *TINY)
    assert resumed.exit_code == 2 and "size mismatch for" in resumed.output, resumed.output
    assert sorted(os.listdir(tmp_path)) == ["broken", "mine.pt"]


@pytest.mark.slow
def test_infer_and_evaluate_refuse_nan_weights_and_write_nothing(tiny_run, reference, tmp_path):
    broken = _copy_run(tiny_run, tmp_path / "broken")
    ckpt = runfiles.load_checkpoint(str(broken))
    name = next(iter(ckpt["model"]))
    ckpt["model"][name].view(-1)[0] = float("nan")
    state = {k: ckpt[k] for k in ("epoch", "history", "identity_digest")}
    runfiles.save_checkpoint(str(broken), model_state=ckpt["model"], optimizer_state=ckpt["optimizer"], **state)
    for command, args in _commands(broken, reference, tmp_path).items():
        result = _invoke(*args)
        assert result.exit_code == 2, (command, result.output)
        assert "1 weight value(s) are NaN or infinite" in result.output and "smaller --lr" in result.output
    assert sorted(os.listdir(tmp_path)) == ["broken"]
