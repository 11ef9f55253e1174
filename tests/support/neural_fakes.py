"""An in-memory stand-in for an opened dataset folder (pipeline.neural.data.open_dataset),
so the training loop is tested in seconds without Mitsuba."""

from __future__ import annotations

import os

import numpy as np
import torch
from click.testing import CliRunner
from torch.utils.data import Dataset

from cli import main
from pipeline.neural import runfiles
from pipeline.neural.network import NeuralRenderer
from pipeline.neural.train import TrainConfig


class _Items(Dataset):
    def __init__(self, items):
        self.items = items

    def __len__(self):
        return len(self.items)

    def __getitem__(self, i):
        return self.items[i]


class FakeSource:
    """``materials`` x ``lights`` samples at ``resolution``: diffuse-shaded random maps."""

    def __init__(self, materials: int = 4, lights: int = 2, resolution: int = 32, seed: int = 0):
        self.resolution = resolution
        self.identity = {"fake": True, "materials": materials, "lights": lights, "seed": seed}
        self.items = []
        rng = np.random.default_rng(seed)
        for m in range(materials):
            diffuse = np.broadcast_to(rng.random(3)[:, None, None], (3, resolution, resolution))
            rough = np.full((3, resolution, resolution), rng.random())
            normal = np.zeros((3, resolution, resolution))
            normal[2] = 1.0
            maps = np.concatenate([diffuse, np.zeros_like(diffuse), (normal + 1) / 2, rough]).astype(np.float32)
            for l in range(lights):
                el = rng.uniform(0.2, 1.4)
                az = rng.uniform(0, 2 * np.pi)
                d = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
                light = np.array([*d, rng.uniform(1, 10)], dtype=np.float32)
                shade = np.linspace(0.2, 1.0, resolution)[None, :, None] * d[2]
                target = np.clip(diffuse * shade, 0, 1).astype(np.float32)
                self.items.append(
                    {
                        "maps": torch.from_numpy(maps.copy()),
                        "light": torch.from_numpy(light),
                        "target": torch.from_numpy(target),
                        "mask": torch.ones(1, resolution, resolution),
                        "id": f"m{m:06d}_l{l}",
                        "material_id": f"m{m:06d}",
                    }
                )
        self.material_ids = sorted({it["material_id"] for it in self.items})

    def subset(self, material_ids):
        keep = set(material_ids)
        return _Items([it for it in self.items if it["material_id"] in keep])


def train_config(tmp_path, name="run", **kw) -> TrainConfig:
    """A small CPU training run in ``tmp_path/name`` over a FakeSource; ``kw`` overrides."""
    base = dict(
        dataset="(in memory)",
        out=str(tmp_path / name),
        epochs=2,
        batch_size=2,
        lr=1e-3,
        loss="l1",
        device="cpu",
        precision="fp32",  # the same computation on every CPU (the default, auto, is bf16 on some)
        seed=5,
        test_fraction=0.25,
    )
    base.update(kw)
    return TrainConfig(**base)


#: The files a finished training run folder holds (with a held-out split).
#: The options of the tiny run that the checkpoint, run-file and link tests share (conftest's
#: ``tiny_run``, one epoch); a test that resumes it passes them again.
TINY = ["--loss", "l1", "--resolution", "16", "--width", "0.1", "--batch-size", "8", "--seed", "3"]
RUN_FILES = ["checkpoint-best.pt", "checkpoint.pt", "config.json", "log.csv", "log.jsonl", "loss.png"]


def untrained_run(folder, resolution: int, digest: str = "untrained") -> None:
    """A run folder whose network is ``resolution`` pixels with its initial (random) weights:
    what evaluate reads of a run, without training one."""
    os.makedirs(folder)
    runfiles.write_json(
        os.path.join(folder, runfiles.CONFIG),
        {
            "identity": {"dataset": {}},
            "identity_digest": digest,
            "network": {"resolution": resolution},
            "tonemap": {"name": "reinhard+srgb", "exposure": 4.0},
        },
    )
    runfiles.save_checkpoint(
        str(folder),
        epoch=1,
        model_state=NeuralRenderer(resolution).state_dict(),
        optimizer_state={},
        history=[],
        identity_digest=digest,
    )


def assert_checkpoint_refused(run, out, commands: dict, words: str) -> None:
    """Each command line of ``commands`` (its name: its arguments) is refused (exit code 2)
    naming ``run``'s checkpoint.pt and saying ``words``, without a traceback; ``run`` is left
    as it was and ``out``, made empty here, stays empty."""
    out.mkdir()
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    for command, args in commands.items():
        result = CliRunner().invoke(main, [str(a) for a in args])
        assert result.exit_code == 2, (command, result.exit_code, result.output, result.exception)
        assert f"{run / 'checkpoint.pt'}: " in result.output, (command, result.output)
        assert words in result.output, (command, result.output)
        assert "Traceback" not in result.output and len(result.output) < 1500, (command, result.output)
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before
    assert list(out.iterdir()) == []


def epoch_threads(monkeypatch) -> list[int]:
    """torch's thread count at each training epoch from now on (``train_epoch`` spied on)."""
    from pipeline.neural import train as train_module

    seen = []
    real = train_module.train_epoch

    def spy(*args, **kwargs):
        seen.append(torch.get_num_threads())
        return real(*args, **kwargs)

    monkeypatch.setattr(train_module, "train_epoch", spy)
    return seen
