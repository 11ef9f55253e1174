"""The sizes of a training run's two checkpoints, measured: checkpoint.pt (weights and Adam's
state, to resume) and checkpoint-best.pt (weights only), at 64 and 400 px, widths 1 and 0.5.

    .venv/bin/python scripts/checkpoint_sizes.py

Each network takes one Adam step (so the optimizer holds its two moments, as after an epoch)
and is saved with the run's own writer (pipeline.neural.runfiles.save_checkpoint) into a
temporary folder; the history a real run adds is a few kB.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch  # noqa: E402

from pipeline.neural import runfiles  # noqa: E402
from pipeline.neural.network import NeuralRenderer, parameter_count  # noqa: E402


def sizes(resolution: int, width: float) -> tuple[int, int, int]:
    torch.manual_seed(0)
    model = NeuralRenderer(resolution, width)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    model(torch.rand(1, 12, resolution, resolution), torch.rand(1, 4)).mean().backward()
    optimizer.step()
    state = dict(epoch=1, model_state=model.state_dict(), history=[], identity_digest="-")
    with tempfile.TemporaryDirectory() as folder:
        runfiles.save_checkpoint(folder, optimizer_state=optimizer.state_dict(), **state)
        runfiles.save_checkpoint(folder, name=runfiles.BEST_CHECKPOINT, optimizer_state=None, **state)
        last = os.path.getsize(os.path.join(folder, runfiles.CHECKPOINT))
        best = os.path.getsize(os.path.join(folder, runfiles.BEST_CHECKPOINT))
    return parameter_count(model), last, best


def main() -> int:
    for resolution in (64, 400):
        for width in (1.0, 0.5):
            params, last, best = sizes(resolution, width)
            print(
                f"{resolution} px, --width {width:g}: {params:,} parameters; checkpoint.pt {last / 1e6:.1f} MB, "
                f"checkpoint-best.pt {best / 1e6:.1f} MB"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
