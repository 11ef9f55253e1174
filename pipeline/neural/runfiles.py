"""A training run's folder: config.json, log.jsonl, log.csv, checkpoint.pt, checkpoint-best.pt, loss.png.

Every file is replaced atomically (:mod:`pipeline.store.atomic`: temporary file in the same
folder, fsync, rename), so a kill at any instant leaves the previous complete file or the new one.

A run folder is untrusted input, as a dataset folder is: ``config.json`` is read bounded
(:func:`pipeline.store.bounded_read.read_json_checked`: a regular file, its size and JSON
structure bounded before it is parsed) and checked field by field (:func:`config_problem`)
before any field is used; a checkpoint's zip archive is checked against a budget derived
from the network's parameter count before ``torch.load`` decompresses anything
(:func:`checkpoint_archive_problem`), every tensor's dtype, shape, strides and storage
against the network from the archive's metadata before any tensor is made
(:mod:`pipeline.neural.checkpoint_meta`), then its content by type, and refused when a weight
is not finite. Each refusal is a ShaderballError naming the file and the field (the tensor).
Nothing is written through a symbolic link inside the run folder (:func:`refuse_links`,
:mod:`pipeline.store.links`).

The checks of each file (a log entry, config.json, a checkpoint) are pipeline.neural.run_checks.
"""

from __future__ import annotations

import csv
import errno
import io
import json
import os
import stat

import torch

from pipeline.errors import ShaderballError, quoted
from pipeline.neural import checkpoint_meta
from pipeline.neural.checkpoint_meta import shown
from pipeline.neural.config import InferRequest
from pipeline.neural.network import (
    NeuralRenderer,
    check_network_resolution,
    check_width,
    network_from_config,
    parameter_count,
)
from pipeline.neural.run_checks import (
    archive_problem,
    checkpoint_content_problem,
    config_problem,
    epoch_problem,
    largest_network_parameters,
)
from pipeline.neural.runfolder import (  # noqa: F401 - the run files' names, read here as runfiles.NAME
    BEST_CHECKPOINT,
    CHECKPOINT,
    CONFIG,
    LOG,
    LOG_CSV,
    LOSS_PNG,
    RUN_FILES,
    refuse_links,
)
from pipeline.store.atomic import write_bytes_atomic
from pipeline.store.bounded_read import MAX_JSON_BYTES, read_bytes, read_json_checked, structure_problem

#: The per-epoch log.csv's columns, in this order.
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
#: What `--checkpoint` names: the last epoch's or the best held-out one's, or else a file.
CHECKPOINT_CHOICES = {"last": CHECKPOINT, "best": BEST_CHECKPOINT}
CHECKPOINT_FORMAT = "shaderball-neural-checkpoint"
CHECKPOINT_VERSION = 1


def write_json(path: str, obj, inside: str | None = None) -> None:
    """``obj`` as indented JSON (``inside``: the folder written into, no link followed in it)."""
    write_bytes_atomic(path, (json.dumps(obj, indent=2, sort_keys=True) + "\n").encode(), inside)


def write_log(path: str, history: list[dict], inside: str | None = None) -> None:
    text = "".join(json.dumps(entry, sort_keys=True) + "\n" for entry in history)
    write_bytes_atomic(path, text.encode(), inside)


#: Largest log.jsonl read (an epoch's line is ~1 kB: 100,000 epochs take ~100 MB).
MAX_LOG_BYTES = 256 << 20


def read_log(run_dir: str) -> list[dict]:
    """The run's epochs from log.jsonl ([] when there is none yet), read bounded: each line's
    JSON structure is counted before it is parsed (pipeline.store.folder) and must be an
    epoch (:func:`epoch_problem`)."""
    path = os.path.join(run_dir, LOG)
    if not os.path.isfile(path):
        return []
    try:
        data = read_bytes(path, MAX_LOG_BYTES)
    except OSError as exc:
        raise ShaderballError(f"{path}: not a run's log ({exc.strerror or exc})") from None
    history = []
    for number, line in enumerate(data.split(b"\n"), start=1):
        if not line.strip():
            continue
        problem = structure_problem(line)
        if problem is None:
            try:
                entry = json.loads(line)
                problem = epoch_problem(entry)
            except (UnicodeDecodeError, ValueError, RecursionError) as exc:
                problem = f"not JSON ({type(exc).__name__})"
        if problem:
            raise ShaderballError(f"{path} line {number}: not a run's log ({problem})")
        history.append(entry)
    return history


def write_log_csv(path: str, history: list[dict], inside: str | None = None) -> None:
    write_bytes_atomic(path, log_csv(history), inside)


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


#: Largest config.json read: its split lists every material id (the paper's 10,000 take
#: ~0.2 MB); its JSON structure is bounded in proportion (pipeline.store.folder).
MAX_CONFIG_BYTES = 32 * MAX_JSON_BYTES


def read_config(run_dir: str) -> dict:
    """The run's config.json, read bounded and checked field by field (:func:`config_problem`);
    a ShaderballError naming the file and the field when it cannot be used."""
    path = os.path.join(run_dir, CONFIG)
    config, why = read_json_checked(path, MAX_CONFIG_BYTES)
    if why == "missing":
        raise InferRequest.field_error(
            "run",
            run_dir,
            "a training run folder: make one with `shaderball train`",
            what=f"{quoted(run_dir)} is not a training run (no {CONFIG})",
        )
    if why is not None:
        raise ShaderballError(f"{path}: not readable JSON ({why}); the run folder is damaged")
    problem = config_problem(config)
    if problem:
        raise ShaderballError(f"{path}: {problem}; the run folder is damaged (train a new run with `shaderball train`)")
    field = f"{path}: network.resolution"
    check_network_resolution(config["network"]["resolution"], field)
    check_width(config["network"].get("width", 1.0), f"{path}: network.width")
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
    write_bytes_atomic(os.path.join(run_dir, name), buffer.getvalue(), inside=run_dir)


def checkpoint_path(run_dir: str, checkpoint: str = "last") -> str:
    """The file ``--checkpoint`` names: ``last``, ``best`` (in the run folder) or a file."""
    if checkpoint in CHECKPOINT_CHOICES:
        return os.path.join(run_dir, CHECKPOINT_CHOICES[checkpoint])
    return checkpoint


def _remedy(checkpoint: str) -> str:
    """What to do about an unusable checkpoint: a run's own can be restored or removed; a
    file the user named is replaced by one this run wrote."""
    if checkpoint in CHECKPOINT_CHOICES:
        return "restore it, or remove it to train again from the start"
    return "name a checkpoint this run's configuration wrote (--checkpoint last, best, or such a file)"


def load_checkpoint(
    run_dir: str,
    identity_digest: str | None = None,
    checkpoint: str = "last",
    parameters: int | None = None,
    network: torch.nn.Module | None = None,
) -> dict:
    """The run's checkpoint (``last``, ``best`` or a file), or a ShaderballError naming the file
    when it is missing, over the budget of a network of ``parameters`` (default: ``network``'s,
    else the largest network), corrupt, belongs to another configuration, holds a tensor that
    is not ``network``'s (default: the network of the run's config.json, built on the meta
    device) or non-finite weights. Every tensor is checked from the file's metadata before
    ``torch.load`` reads it (:mod:`pipeline.neural.checkpoint_meta`)."""
    path = checkpoint_path(run_dir, checkpoint)
    if not os.path.lexists(path):
        _missing(path, checkpoint)
    # The run's own checkpoint is never read through a link; a file the user names may be one.
    follow = 0 if checkpoint not in CHECKPOINT_CHOICES else os.O_NOFOLLOW
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | follow)
    except OSError as exc:
        why = "a symbolic link: not followed" if exc.errno == errno.ELOOP else (exc.strerror or str(exc))
        raise ShaderballError(f"{path}: not a readable checkpoint ({why}); {_remedy(checkpoint)}") from None
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise ShaderballError(f"{path}: not a regular file, not read; {_remedy(checkpoint)}")
        budget = parameters or (parameter_count(network) if network is not None else largest_network_parameters())
        problem, archive = archive_problem(f, budget)
        if problem:
            raise ShaderballError(f"{path}: a corrupt checkpoint, {problem}; {_remedy(checkpoint)}")
        try:
            root, tensors = checkpoint_meta.read_tensor_refs(archive)
            _check_header(root, path, run_dir, identity_digest)
            arch = checkpoint_meta.Architecture.of(network if network is not None else _config_network(run_dir))
            checkpoint_meta.check_tensors(tensors, arch)
        except checkpoint_meta.CheckpointRefused as exc:
            raise _refused(exc, path, run_dir, checkpoint) from None
        ckpt = _torch_load(f, path, checkpoint)
    problem = checkpoint_meta.loaded_problem(ckpt, tensors)
    if problem:
        raise ShaderballError(f"{path}: a corrupt checkpoint: {problem}; {_remedy(checkpoint)}")
    _check_header(ckpt, path, run_dir, identity_digest)
    ckpt = checkpoint_meta.copied(ckpt)
    problem = checkpoint_content_problem(ckpt)
    if problem:
        raise ShaderballError(f"{path}: a corrupt checkpoint: {problem}; {_remedy(checkpoint)}")
    return ckpt


def _missing(path: str, checkpoint: str):
    """The refusal of a checkpoint that is not there, as ``checkpoint`` names it."""
    if checkpoint == "best":
        raise InferRequest.field_error(
            "checkpoint",
            checkpoint,
            "last",
            what=f"best: the run has no {path} (it holds no materials out, or has not finished an epoch yet)",
        )
    if checkpoint == "last":
        raise ShaderballError(f"{path}: no checkpoint (the run has not finished an epoch yet)")
    raise InferRequest.field_error(
        "checkpoint", checkpoint, "last, best, or a checkpoint file", what=f"{quoted(path)}: no such file"
    )


def _config_network(run_dir: str) -> NeuralRenderer:
    """The network the run's config.json describes, on the meta device (nothing allocated)."""
    config = read_config(run_dir)
    return network_from_config(config["network"], "meta")


def _check_header(ckpt, path: str, run_dir: str, identity_digest: str | None) -> None:
    """The checkpoint's format, version and configuration (of what data.pkl holds, or torch.load read)."""
    if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
        raise ShaderballError(f"{path}: not a shaderball checkpoint")
    if ckpt.get("version") != CHECKPOINT_VERSION:
        raise ShaderballError(
            f"{path}: checkpoint version {shown(ckpt.get('version'))}; this shaderball reads version "
            f"{CHECKPOINT_VERSION}"
        )
    if identity_digest is not None and ckpt.get("identity_digest") != identity_digest:
        raise ShaderballError(
            f"{path}: the checkpoint belongs to another configuration than {os.path.join(run_dir, CONFIG)}"
        )


def _refused(exc: checkpoint_meta.CheckpointRefused, path: str, run_dir: str, checkpoint: str) -> ShaderballError:
    """A tensor refused from its metadata: weights of another network, or a corrupt file."""
    if not exc.fits:
        return not_fitting(exc.text, path, checkpoint, os.path.join(run_dir, CONFIG))
    return ShaderballError(f"{path}: a corrupt checkpoint: {exc.text}; {_remedy(checkpoint)}")


def _torch_load(f, path: str, checkpoint: str):
    """``torch.load`` of the checked file (the same one: its descriptor), its storages mapped
    from the file (nothing allocated beyond it) and weights only."""
    same = f"/proc/self/fd/{f.fileno()}"
    try:
        return torch.load(same if os.path.exists(same) else path, map_location="cpu", weights_only=True, mmap=True)
    except Exception as exc:  # a truncated or foreign file raises any of several types
        raise ShaderballError(
            f"{path}: a corrupt checkpoint, not readable by torch.load ({type(exc).__name__}); {_remedy(checkpoint)}"
        ) from exc


def weights_mismatch(exc: RuntimeError, path: str, checkpoint: str, config_path: str) -> ShaderballError:
    """``load_state_dict``'s refusal as one whole message (every line of torch's, bounded)."""
    detail = "; ".join(line.strip() for line in str(exc).splitlines() if line.strip())
    return not_fitting(detail, path, checkpoint, config_path)


def not_fitting(detail: str, path: str, checkpoint: str, config_path: str) -> ShaderballError:
    """Weights of another network than ``config_path``'s: what to do, right for the case."""
    if len(detail) > 2000:
        detail = detail[:1997] + "..."
    if checkpoint in CHECKPOINT_CHOICES:
        what = f"the run folder's checkpoint does not match its {config_path}: {_remedy(checkpoint)}"
    else:
        what = f"it is not a checkpoint of the network {config_path} describes: {_remedy(checkpoint)}"
    return ShaderballError(f"{path}: the weights do not fit the network ({detail}); {what}")
