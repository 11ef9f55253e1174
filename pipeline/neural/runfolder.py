"""A training run folder's file names and the refusals of a folder a run would write into,
without torch: `shaderball train` refuses a bad --out before torch is loaded
(:meth:`pipeline.neural.config.TrainConfig.check_run`). :mod:`pipeline.neural.runfiles`
reads and writes the files."""

from __future__ import annotations

import os

from pipeline.errors import quoted
from pipeline.store.links import first_link

CONFIG = "config.json"
LOG = "log.jsonl"
#: The per-epoch log as CSV, for spreadsheets and plotting tools.
LOG_CSV = "log.csv"
CHECKPOINT = "checkpoint.pt"
#: The checkpoint of the epoch with the best held-out PSNR so far (runs with a held-out split):
#: the weights only, no optimizer state.
BEST_CHECKPOINT = "checkpoint-best.pt"
LOSS_PNG = "loss.png"
#: Every file a training run writes into its folder.
RUN_FILES = (CONFIG, LOG, LOG_CSV, CHECKPOINT, BEST_CHECKPOINT, LOSS_PNG)


def refuse_links(request, field: str, value, roots, paths) -> None:
    """Refuse (``request``'s ``field``, exit 2) the first of ``paths`` that is, or passes
    through, a symbolic link inside one of ``roots`` (a run folder, an output folder):
    :func:`pipeline.store.links.first_link`, checked before anything is written."""
    found = first_link(roots, paths)
    if found:
        raise request.field_error(field, value, f"remove the link, or name another {{{field}}}", what=found[1])


def check_run_folder(request, field: str, run_dir: str | None) -> None:
    """``run_dir`` (``request``'s ``field``) as the folder of a run: named, a new or empty folder
    or a run's (with config.json), no run file through a symbolic link."""
    if not run_dir:
        raise request.field_error(field, run_dir, "name the run folder (or pass {benchmark})", what="missing")
    if os.path.exists(run_dir) and not os.path.isdir(run_dir):
        raise request.field_error(field, run_dir, "a folder", what=f"{quoted(run_dir)} is a file")
    if os.path.isdir(run_dir) and os.listdir(run_dir) and not os.path.isfile(os.path.join(run_dir, CONFIG)):
        raise request.field_error(
            field,
            run_dir,
            f"a new or empty folder, or a run folder (with {CONFIG})",
            what=f"{quoted(run_dir)} holds other files",
        )
    refuse_links(request, field, run_dir, [run_dir], [os.path.join(run_dir, n) for n in RUN_FILES])
