"""A training run's folder: config.json, log.jsonl, log.csv, checkpoint.pt, checkpoint-best.pt, loss.png.

Every file is replaced atomically (:mod:`pipeline.store.atomic`: temporary file in the same
folder, fsync, rename), so a kill at any instant leaves the previous complete file or the new one.
"""

from __future__ import annotations

import csv
import io
import json
import os

import torch

from pipeline.errors import ShaderballError
from pipeline.store.atomic import write_bytes_atomic

CONFIG = "config.json"
LOG = "log.jsonl"
#: The per-epoch log as CSV, for spreadsheets and plotting tools; these columns, in this order.
LOG_CSV = "log.csv"
CSV_COLUMNS = (
    "epoch",
    "train_loss",
    "test_loss",
    "test_psnr",
    "time_s",
    "lr",
    "test_saturated",
    "warnings",
    "train_eval_loss",
    "train_psnr",
    "samples_per_s",
)
CHECKPOINT = "checkpoint.pt"
#: The checkpoint of the epoch with the best held-out PSNR so far (runs with a held-out split):
#: the weights only, no optimizer state.
BEST_CHECKPOINT = "checkpoint-best.pt"
#: What `--checkpoint` names: the last epoch's or the best held-out one's, or else a file.
CHECKPOINT_CHOICES = {"last": CHECKPOINT, "best": BEST_CHECKPOINT}
LOSS_PNG = "loss.png"
CHECKPOINT_FORMAT = "shaderball-neural-checkpoint"
CHECKPOINT_VERSION = 1


def write_json(path: str, obj) -> None:
    write_bytes_atomic(path, (json.dumps(obj, indent=2, sort_keys=True) + "\n").encode())


def write_log(path: str, history: list[dict]) -> None:
    text = "".join(json.dumps(entry, sort_keys=True) + "\n" for entry in history)
    write_bytes_atomic(path, text.encode())


def read_log(run_dir: str) -> list[dict]:
    """The run's epochs from log.jsonl ([] when there is none yet)."""
    path = os.path.join(run_dir, LOG)
    if not os.path.isfile(path):
        return []
    try:
        with open(path, encoding="utf-8") as f:
            return [json.loads(line) for line in f if line.strip()]
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ShaderballError(f"{path}: not a run's log ({exc})") from None


def write_log_csv(path: str, history: list[dict]) -> None:
    write_bytes_atomic(path, log_csv(history))


def log_csv(history: list[dict]) -> bytes:
    """The epochs as CSV, CSV_COLUMNS in order (warnings joined by ' | ')."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for entry in history:
        row = []
        for column in CSV_COLUMNS:
            value = entry.get(column)
            if column == "warnings":
                value = " | ".join(value or ())
            row.append("" if value is None else (repr(value) if isinstance(value, float) else value))
        writer.writerow(row)
    return buffer.getvalue().encode()


def read_config(run_dir: str) -> dict:
    path = os.path.join(run_dir, CONFIG)
    if not os.path.isfile(path):
        raise ShaderballError(
            f"RUN: {run_dir!r} is not a training run (no {CONFIG}); make one with `shaderball train DATASET --out RUN`"
        )
    try:
        with open(path, encoding="utf-8") as f:
            config = json.load(f)
    except (OSError, ValueError) as exc:
        raise ShaderballError(f"{path}: not readable JSON ({exc})") from exc
    if not isinstance(config, dict) or "identity" not in config:
        raise ShaderballError(f"{path}: not a shaderball training config (no 'identity')")
    return config


def save_checkpoint(
    run_dir: str,
    *,
    epoch: int,
    model_state: dict,
    optimizer_state: dict | None,
    history: list[dict],
    identity_digest: str,
    name: str = CHECKPOINT,
) -> None:
    """``optimizer_state`` None: the weights only (the best checkpoint: a third of the size of one
    with Adam's two moments; a run resumes from the last checkpoint, which keeps them)."""
    content = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "epoch": int(epoch),
        "identity_digest": identity_digest,
        "model": {k: v.detach().cpu() for k, v in model_state.items()},
        "history": history,
    }
    if optimizer_state is not None:
        content["optimizer"] = optimizer_state
    buffer = io.BytesIO()
    torch.save(content, buffer)
    write_bytes_atomic(os.path.join(run_dir, name), buffer.getvalue())


def checkpoint_path(run_dir: str, checkpoint: str = "last") -> str:
    """The file ``--checkpoint`` names: ``last``, ``best`` (in the run folder) or a file."""
    if checkpoint in CHECKPOINT_CHOICES:
        return os.path.join(run_dir, CHECKPOINT_CHOICES[checkpoint])
    return checkpoint


def load_checkpoint(run_dir: str, identity_digest: str | None = None, checkpoint: str = "last") -> dict:
    """The run's checkpoint (``last``, ``best`` or a file), or a ShaderballError naming the file
    when it is missing, corrupt or belongs to another configuration."""
    path = checkpoint_path(run_dir, checkpoint)
    if not os.path.isfile(path):
        if checkpoint == "best":
            raise ShaderballError(
                f"--checkpoint best: {path}: no best checkpoint (the run holds no materials out, "
                "or has not finished an epoch yet); use --checkpoint last"
            )
        if checkpoint == "last":
            raise ShaderballError(f"{path}: no checkpoint (the run has not finished an epoch yet)")
        raise ShaderballError(f"--checkpoint: {path!r}: no such file (allowed: last, best, or a checkpoint file)")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # a truncated or foreign file raises any of several types
        raise ShaderballError(
            f"{path}: a corrupt checkpoint, not readable by torch.load ({type(exc).__name__}); "
            "restore it, or remove it to train again from the start"
        ) from exc
    if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
        raise ShaderballError(f"{path}: not a shaderball checkpoint")
    if ckpt.get("version") != CHECKPOINT_VERSION:
        raise ShaderballError(
            f"{path}: checkpoint version {ckpt.get('version')!r}; this shaderball reads version {CHECKPOINT_VERSION}"
        )
    if identity_digest is not None and ckpt.get("identity_digest") != identity_digest:
        raise ShaderballError(
            f"{path}: the checkpoint belongs to another configuration than {os.path.join(run_dir, CONFIG)}"
        )
    return ckpt
