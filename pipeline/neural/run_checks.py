"""What makes each file of a run folder usable, checked before any of it is used (a run
folder is untrusted input): a log entry by type and range (:func:`epoch_problem`), config.json
field by field (:func:`config_problem`), a checkpoint's zip archive against a budget derived
from the network's parameter count before ``torch.load`` decompresses anything
(:func:`checkpoint_archive_problem`), then its content by type
(:func:`checkpoint_content_problem`), the optimiser state a resume loads
(:func:`optimizer_problem`) and its weights' finiteness (:func:`nonfinite_weights`). Each
returns what is wrong, or None."""

from __future__ import annotations

import functools
import math
import os
import struct
import sys
import zipfile

import torch

from pipeline.neural import checkpoint_meta
from pipeline.neural.checkpoint_meta import shown
from pipeline.neural.limits import INTEGER_RANGES
from pipeline.neural.network import NeuralRenderer, parameter_count
from pipeline.store.record_fields import NUMBER, json_type_name, short_json

#: An epoch's numbers that the commands read (a log's line, a checkpoint's history): (field,
#: whether it is required, the lowest and highest value allowed, the range in words). A PSNR
#: is +inf where the images are equal (pipeline.image.metrics.psnr8); nothing else is ever
#: infinite, and no field is ever NaN: a run whose loss turns NaN stops before it saves.
_FINITE = sys.float_info.max
EPOCHNUMBERS = (
    ("epoch", True, 1, INTEGER_RANGES["epochs"][1], f"an integer from 1 to {INTEGER_RANGES['epochs'][1]}"),
    ("train_loss", True, -_FINITE, _FINITE, "a finite number"),
    ("test_loss", False, -_FINITE, _FINITE, "a finite number"),
    ("train_eval_loss", False, -_FINITE, _FINITE, "a finite number"),
    ("test_psnr", False, 0.0, math.inf, "a PSNR >= 0 dB (inf where the images are equal)"),
    ("train_psnr", False, 0.0, math.inf, "a PSNR >= 0 dB (inf where the images are equal)"),
    ("lr", False, 0.0, _FINITE, "a finite number >= 0"),
    ("time_s", False, 0.0, _FINITE, "a finite number >= 0"),
    ("samples_per_s", False, 0.0, _FINITE, "a finite number >= 0"),
    ("test_saturated", False, 0.0, 1.0, "a fraction from 0 to 1"),
    ("schedule_epochs", False, 1, INTEGER_RANGES["epochs"][1], f"an integer from 1 to {INTEGER_RANGES['epochs'][1]}"),
)
#: Warnings an epoch lists at most (train writes two kinds), and characters in one.
MAX_EPOCH_WARNINGS, MAX_WARNING_CHARS = 16, 2000


def epoch_problem(entry) -> str | None:
    """Why an epoch of a log or a checkpoint's history cannot be used, or None: the fields
    the commands read, by type and range (:data:`EPOCHNUMBERS`), and its warnings."""
    if not isinstance(entry, dict):
        return f"an epoch is {json_type_name(entry)}, not an object"
    for field, required, lo, hi, allowed in EPOCHNUMBERS:
        value = entry.get(field)
        if value is None and not required:
            continue
        kind = int if field in ("epoch", "schedule_epochs") else NUMBER
        if isinstance(value, bool) or not isinstance(value, kind):
            return f"{field} is {json_type_name(value)} ({_spelled(value)}), not {allowed}"
        # an int compares with a float exactly in Python, whatever its size; NaN fails both
        if not lo <= value <= hi:
            return f"{field} is {_spelled(value)}, not {allowed}"
    warnings = entry.get("warnings")
    if warnings is not None and (
        not isinstance(warnings, list)
        or len(warnings) > MAX_EPOCH_WARNINGS
        or not all(isinstance(w, str) and len(w) <= MAX_WARNING_CHARS for w in warnings)
    ):
        return f"warnings is {_spelled(warnings)}, not a list of at most {MAX_EPOCH_WARNINGS} lines of text"
    return None


def _spelled(value) -> str:
    """A value of a log line or a checkpoint's history as JSON spells it (cut short), or, where
    JSON cannot (an integer of over 4,300 digits, a pickled object), bounded (:func:`shown`)."""
    try:
        return short_json(value)
    except (TypeError, ValueError, RecursionError):
        return shown(value)


#: What the commands read of config.json, and its type; a path names a field in an object.
CONFIG_FIELDS = {
    "identity": dict,
    "identity_digest": str,
    "network": dict,
    "network.resolution": int,
    "tonemap": dict,
    "tonemap.exposure": NUMBER,
}
#: Fields that may be absent or null, and their type when present.
OPTIONAL_CONFIG_FIELDS = {
    "network.width": NUMBER,
    "network.parameters": int,
    "options": dict,
    "identity.dataset": dict,
    "identity.dataset.variant": str,
    "baseline": dict,
    "baseline.test_psnr": NUMBER,
    "split": dict,
    "split.train": list,
    "split.test": list,
}


def _lookup(config: dict, field: str):
    """(found, value) of a dotted field; not found when a parent is absent or null."""
    value = config
    for part in field.split("."):
        if not isinstance(value, dict) or value.get(part) is None:
            return False, None
        value = value[part]
    return True, value


def _kind_text(kind) -> str:
    if kind == NUMBER:
        return "a number"
    kinds = kind if isinstance(kind, tuple) else (kind,)
    return " or ".join(
        {dict: "an object", list: "an array", str: "a string", int: "an integer", float: "a number"}[k] for k in kinds
    )


def config_problem(config) -> str | None:
    """Why a run's config cannot be used (the field, its type or value, what is allowed), or None."""
    if not isinstance(config, dict):
        return f"not a shaderball training config (a JSON {json_type_name(config)}, not an object)"
    for fields, required in ((CONFIG_FIELDS, True), (OPTIONAL_CONFIG_FIELDS, False)):
        for field, kind in fields.items():
            found, value = _lookup(config, field)
            if not found:
                parent = field.rpartition(".")[0]
                if required and (not parent or _lookup(config, parent)[0]):
                    return f"no {field} (a shaderball training config has one)"
                continue
            if isinstance(value, bool) or not isinstance(value, kind):
                return f"{field} is {json_type_name(value)} ({short_json(value)}), not {_kind_text(kind)}"
    exposure = config["tonemap"]["exposure"]
    if not (math.isfinite(exposure) and exposure > 0):
        return f"tonemap.exposure is {exposure!r}, not a positive number"
    for name in ("train", "test"):
        ids = (config.get("split") or {}).get(name) or []
        bad = next((i for i in ids if not isinstance(i, str)), None)
        if bad is not None:
            return f"split.{name} holds {json_type_name(bad)} ({short_json(bad)}), not only material ids (strings)"
    return None


#: Bytes a checkpoint holds besides its tensors' (the pickled history and names, the zip
#: records): a 100,000-epoch log pickles to ~40 MB.
CHECKPOINT_SLACK_BYTES = 64 << 20
#: A checkpoint holds the weights, and Adam's two moments of each: 3 float32 copies.
CHECKPOINT_COPIES = 3
#: Members of a checkpoint's zip archive: one per tensor (the network's ~60, Adam's state of
#: each) and a few records; a zip64 archive (member count 0xFFFF) is never one.
MAX_CHECKPOINT_MEMBERS = 10_000
_EOCD = b"PK\x05\x06"


def checkpoint_budget(parameters: int) -> int:
    """The most bytes a checkpoint of a network of ``parameters`` holds, decompressed."""
    return CHECKPOINT_COPIES * 4 * parameters + CHECKPOINT_SLACK_BYTES


@functools.cache
def largest_network_parameters() -> int:
    """Parameters of the largest network a config may name (counted on torch's meta device:
    nothing allocated): the budget of a checkpoint read without its config."""
    with torch.device("meta"):
        return parameter_count(NeuralRenderer(4096, 1.0))


def checkpoint_archive_problem(path: str, parameters: int) -> str | None:
    """Why the checkpoint file at ``path`` is not one ``torch.save`` writes for a network of
    ``parameters`` (None if it may be): see :func:`archive_problem`."""
    try:
        with open(path, "rb") as f:
            return archive_problem(f, parameters)[0]
    except OSError as exc:
        return f"not a readable zip archive ({exc})"


def archive_problem(f, parameters: int) -> tuple[str | None, zipfile.ZipFile | None]:
    """(why the open checkpoint file ``f`` is not one ``torch.save`` writes for a network of
    ``parameters``, or None; its zip directory when it may be): a zip archive over the budget,
    holding more members than a checkpoint has, or a compressed member (``torch.save`` stores
    members: a DEFLATE member could expand 1,000-fold when ``torch.load`` reads it). Only the
    archive's directory is read; nothing is decompressed."""
    budget = checkpoint_budget(parameters)
    try:
        size = os.fstat(f.fileno()).st_size
        if size > budget:
            return f"{size} bytes, over the {budget} a checkpoint of {parameters:,} parameters may hold", None
        f.seek(max(0, size - 22 - 65535))
        tail = f.read()
        at = tail.rfind(_EOCD)
        if at < 0 or at + 22 > len(tail):
            return "not a complete zip archive (torch.save writes one)", None
        entries = struct.unpack_from("<H", tail, at + 10)[0]
        if entries > MAX_CHECKPOINT_MEMBERS:
            return (
                f"a zip archive of {entries} members (0xFFFF: a zip64 archive), more than a checkpoint "
                f"holds (at most {MAX_CHECKPOINT_MEMBERS})"
            ), None
        f.seek(0)
        archive = zipfile.ZipFile(f)
        members = archive.infolist()
    except (OSError, zipfile.BadZipFile, ValueError, EOFError) as exc:
        return f"not a readable zip archive ({exc})", None
    total = 0
    for member in members:
        if member.compress_type != zipfile.ZIP_STORED or member.compress_size != member.file_size:
            return (
                f"member {short_json(member.filename)} is compressed ({member.compress_size} bytes "
                f"holding {member.file_size}); torch.save stores its members uncompressed"
            ), None
        total += member.file_size
    if total > budget:
        return (
            f"members of {total} bytes in all, over the {budget} a checkpoint of {parameters:,} parameters may hold"
        ), None
    return None, archive


def checkpoint_content_problem(ckpt: dict) -> str | None:
    """Why a loaded checkpoint's fields cannot be used (type by type, number by range), or None."""
    epoch, most = ckpt.get("epoch"), INTEGER_RANGES["epochs"][1]
    if isinstance(epoch, bool) or not isinstance(epoch, int) or not 0 <= epoch <= most:
        return f"epoch is {shown(epoch)}, not an integer from 0 to {most}"
    model = ckpt.get("model")
    if not isinstance(model, dict) or not all(
        isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in model.items()
    ):
        return "model is not a state dict (names -> tensors)"
    if "optimizer" in ckpt and not isinstance(ckpt["optimizer"], dict):  # the best checkpoint holds none
        return "optimizer is not a state dict"
    history = ckpt.get("history")
    if not isinstance(history, list) or len(history) > most:
        return f"history is not a list of at most {most} epochs"
    problem = next(((i, p) for i, p in enumerate(map(epoch_problem, history)) if p), None)
    if problem:
        return f"history[{problem[0]}]: {problem[1]}"
    bad = nonfinite_weights(model)
    if bad:
        return f"{bad:,} weight value(s) are NaN or infinite: the run diverged (train again with a smaller --lr)"
    return None


#: Keys of an Adam param group that torch's Adam needs; the others it fills in when absent
#: (a checkpoint of an older torch), and a key this torch's Adam does not have is refused.
ADAM_GROUP_REQUIRED = ("params", "lr", "betas", "eps", "weight_decay", "amsgrad")
#: Adam's numbers, the range each must lie in, and that range in words.
ADAM_GROUPNUMBERS = {
    "lr": (0.0, _FINITE, "a finite number >= 0"),
    "eps": (sys.float_info.min, _FINITE, "a finite number > 0"),
    "weight_decay": (0.0, _FINITE, "a finite number >= 0"),
}


def optimizer_problem(saved, fresh: dict) -> str | None:
    """Why ``saved`` (a checkpoint's optimizer state, its tensors checked by
    :mod:`pipeline.neural.checkpoint_meta`) cannot be loaded into the run's Adam, whose new
    state dict is ``fresh``, or None: the groups' keys, numbers (each in range) and flags
    (this run's), the state's entries and the moments' values (finite; the second >= 0)."""
    if not isinstance(saved, dict) or set(saved) != {"state", "param_groups"}:
        return "optimizer is not Adam's state dict (state and param_groups)"
    groups, want = saved["param_groups"], fresh["param_groups"]
    if not isinstance(groups, list) or len(groups) != len(want):
        return f"optimizer['param_groups'] is not a list of {len(want)} group(s)"
    for index, (group, wanted) in enumerate(zip(groups, want)):
        problem = _group_problem(group, wanted)
        if problem:
            return f"optimizer['param_groups'][{index}]{problem}"
    params = [p for g in want for p in g["params"]]
    amsgrad = any(g.get("amsgrad") for g in want)
    state = saved["state"]
    if not isinstance(state, dict) or not all(checkpoint_meta.is_int(k) and k in params for k in state):
        return f"optimizer['state'] is not one entry per parameter (keys 0 to {len(params) - 1})"
    for key, entry in state.items():
        problem = _adam_state_problem(entry, amsgrad)
        if problem:
            return f"optimizer['state'][{key}]{problem}"
    return None


def _keys_problem(value, what: str, required, allowed, owner: str) -> str | None:
    """Why ``value`` is not ``what``, a dict with every key of ``required`` and none outside
    ``allowed`` (keys that ``owner`` has), as text after its name; or None."""
    if not isinstance(value, dict):
        return f" is {shown(value)}, not {what}"
    missing = next((k for k in required if k not in value), None)
    if missing:
        return f" has no {missing!r}"
    extra = next((k for k in value if k not in allowed), None)
    if extra is not None:
        return f" has a key {shown(extra)}, which {owner} does not have"
    return None


def _group_problem(group, wanted: dict) -> str | None:
    """Why a param group is not one of this run's Adam (``wanted``), as text after its name."""
    problem = _keys_problem(group, "a param group", ADAM_GROUP_REQUIRED, wanted, "this torch's Adam")
    if problem:
        return problem
    if group["params"] != wanted["params"]:
        return "['params'] is not the network's parameters in order"
    betas = group["betas"]
    below_1 = math.nextafter(1.0, 0.0)
    if not (isinstance(betas, (tuple, list)) and len(betas) == 2 and all(_number_in(b, 0.0, below_1) for b in betas)):
        return f"['betas'] is {shown(betas)}, not two numbers from 0 to 1 (1 excluded, as torch's Adam requires)"
    for key, (lo, hi, allowed) in ADAM_GROUPNUMBERS.items():
        if not _number_in(group[key], lo, hi):
            return f"[{key!r}] is {shown(group[key])}, not {allowed}"
    for key, value in group.items():
        flag = wanted[key]
        if (
            key not in ADAM_GROUPNUMBERS
            and key not in ("params", "betas")
            and (type(value), value) != (type(flag), flag)
        ):
            return f"[{key!r}] is {shown(value)}, where this run's Adam has {flag!r}"
    return None


def _adam_state_problem(entry, amsgrad: bool) -> str | None:
    """Why one parameter's Adam state cannot be used, as text after its name."""
    keys = ("step", "exp_avg", "exp_avg_sq") + (("max_exp_avg_sq",) if amsgrad else ())
    problem = _keys_problem(entry, "a parameter's state", keys, keys, "Adam's state")
    if problem:
        return problem
    for key in keys:
        value = entry[key]
        if not isinstance(value, torch.Tensor) or not value.is_floating_point():
            return f"[{key!r}] is {_type_article(value)}, not a tensor"
        bad = int(torch.count_nonzero(~torch.isfinite(value)))
        if bad:
            return f"[{key!r}]: {bad:,} value(s) are NaN or infinite"
        negative = int(torch.count_nonzero(value < 0)) if key != "exp_avg" else 0
        if negative:
            return f"[{key!r}]: {negative:,} value(s) are negative"
    return None


def _number_in(value, lo: float, hi: float) -> bool:
    """A number (not a bool) from ``lo`` to ``hi``: an int compares exactly whatever its size; NaN never."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and lo <= value <= hi


def _type_article(value) -> str:
    name = type(value).__name__
    return ("an " if name[:1] in "aeiou" else "a ") + name


def nonfinite_weights(state: dict) -> int:
    """How many values of a state dict's floating-point tensors are NaN or infinite."""
    return sum(
        int(torch.count_nonzero(~torch.isfinite(v)))
        for v in state.values()
        if isinstance(v, torch.Tensor) and v.is_floating_point()
    )
