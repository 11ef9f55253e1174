"""Training of the paper's network on a dataset folder: `shaderball train`.

``train(config)`` opens the dataset, splits it by material, and trains with Adam,
checkpointing every epoch into the run folder. Everything random derives from
``config.seed``: the initial weights (``torch.manual_seed``) and each epoch's order
(a generator seeded by (seed, epoch)), so a run killed at any instant and started again
with the same command continues from its last checkpoint to the same weights as an
uninterrupted run (on the same device, torch version, thread count and --precision).

The run's length and estimates are pipeline.neural.run_clock; its summary and warnings,
pipeline.neural.train_summary; its loss, pipeline.neural.loss_choice.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import logging
import math
import os
import time
from dataclasses import dataclass

import numpy as np
import torch
from torch.utils.data import Subset

from pipeline.errors import ShaderballError, quoted
from pipeline.image.metrics import psnr8
from pipeline.image.tonemap import to_srgb8
from pipeline.neural import run_checks, runfiles, speed
from pipeline.neural.config import TrainConfig
from pipeline.neural.data import batches, open_dataset
from pipeline.neural.distributed import train_distributed
from pipeline.neural.loss import RenderLoss
from pipeline.neural.loss_choice import LossChoice, choose_loss, make_loss
from pipeline.neural.network import NeuralRenderer, light_input, network_from_config, parameter_count
from pipeline.neural.plot import loss_curve_png
from pipeline.neural.run_clock import RunClock, RunLength, StepClock
from pipeline.neural.scene_inputs import InputPlan, with_inputs
from pipeline.neural.splits import (
    SUBSET_STREAM,
    RunSplit,
    run_split,
    select_training_materials,  # noqa: F401 (its callers import it from here)
    split_samples,
)
from pipeline.neural.train_summary import TrainSummary, diverged, epoch_warnings
from pipeline.store.atomic import write_bytes_atomic

#: Config fields that change what a run computes: a resume must match them.
IDENTITY_FIELDS = ("batch_size", "lr", "loss", "vgg_weight", "seed", "resolution", "test_fraction", "exposure")
#: Identity fields with their defaults that join a run's identity only when
#: not the default, so a run made before them resumes. ``epochs`` joins with a cosine
#: schedule, whose learning rate depends on where the run ends.
OPTIONAL_IDENTITY = {
    "width": 1.0,
    "split_seed": None,
    "train_materials": None,
    "schedule": "constant",
    "warmup_epochs": 0.0,
    "held_out_objects": None,
    "held_out_rotations": None,
    "geometry": False,
    "environment_code": 0,
}
#: At most this many training samples are scored after every epoch (the training curve).
TRAIN_EVAL_SAMPLES = 256
#: Key of the per-epoch order stream beside the seed.
ORDER_STREAM = 0x0DE5
log = logging.getLogger(__name__)


def pick_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise TrainConfig.field_error("device", name, "auto or cpu: torch here has no CUDA device")
    return torch.device(name)


def digest(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def epoch_order(n: int, seed: int, epoch: int) -> list[int]:
    """The order of the training samples in ``epoch``: a pure function of (seed, epoch)."""
    state = np.random.SeedSequence([int(seed), ORDER_STREAM, int(epoch)]).generate_state(2, np.uint32)
    generator = torch.Generator().manual_seed(int(state[0]) << 32 | int(state[1]))
    return torch.randperm(n, generator=generator).tolist()


@contextlib.contextmanager
def deterministic_algorithms():
    before = torch.are_deterministic_algorithms_enabled()
    torch.use_deterministic_algorithms(True, warn_only=True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(before)


def batch_to(
    batch: dict, device: torch.device, channels_last: bool = False
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    fmt = speed.memory_format(channels_last)
    maps = batch["maps"].to(device, non_blocking=True, memory_format=fmt)
    light = light_input(batch["light"].to(device, non_blocking=True))
    target = batch["target"].to(device, non_blocking=True, memory_format=fmt)
    return maps, light, target


def batch_extra(batch: dict, device: torch.device) -> tuple:
    """The network's inputs beyond maps and light: the environment codes' rows, where it has them."""
    return (batch["environment_code"].to(device, non_blocking=True),) if "environment_code" in batch else ()


def mean_image(dataset, workers: int, batch_size: int = 16) -> np.ndarray:
    """The training set's mean target in [0, 1], (H, W, 3): the trivial baseline."""
    total, count = None, 0
    for batch in batches(dataset, batch_size, workers):
        s = batch["target"].double().sum(0)
        total = s if total is None else total + s
        count += batch["target"].shape[0]
    return (total / count).permute(1, 2, 0).float().numpy()


def baseline_psnr(mean_target: np.ndarray, test_set, workers: int) -> float | None:
    if test_set is None or len(test_set) == 0:
        return None
    guess = to_srgb8(mean_target)
    values = [
        psnr8(guess, to_srgb8(t.permute(1, 2, 0).numpy()))
        for batch in batches(test_set, 16, workers)
        for t in batch["target"]
    ]
    return float(np.mean(values))


@torch.no_grad()
def evaluate_split(model, loss_fn, dataset, device, batch_size: int, workers: int) -> dict:
    """Mean loss, mean 8-bit PSNR and the fraction of saturated outputs (8-bit 0 or 255)
    over a split, the network in eval mode."""
    model.eval()
    losses, psnrs, n = 0.0, [], 0
    saturated, values = 0, 0
    for batch in batches(dataset, batch_size, workers):
        maps, light, target = batch_to(batch, device)
        pred = model(maps, light, *batch_extra(batch, device))
        losses += float(loss_fn(pred, target)) * maps.shape[0]
        n += maps.shape[0]
        for p, t in zip(pred.cpu(), target.cpu()):
            p8 = to_srgb8(p.permute(1, 2, 0).numpy())
            psnrs.append(psnr8(p8, to_srgb8(t.permute(1, 2, 0).numpy())))
            saturated += int(np.count_nonzero((p8 == 0) | (p8 == 255)))
            values += p8.size
    return {"loss": losses / n, "psnr": float(np.mean(psnrs)), "saturated": saturated / values}


def run_identity(config: TrainConfig, source_identity, resolution, vgg_sha256) -> dict:
    """What a run computes: a resume must match it. The options of OPTIONAL_IDENTITY join only when not
    their defaults, so older runs keep their digest."""
    identity = {k: getattr(config, k) for k in IDENTITY_FIELDS}
    identity.update(resolution=resolution, dataset=source_identity, vgg_sha256=vgg_sha256)
    for key, default in OPTIONAL_IDENTITY.items():
        if getattr(config, key) != default:
            identity[key] = getattr(config, key)
    if config.schedule != "constant":
        identity["epochs"] = config.epochs
    return identity


def learning_rate(config: TrainConfig, step: int, steps_per_epoch: int, held_epochs: int = 0) -> float:
    """The learning rate of optimiser step ``step`` (0-based over the whole run): a linear
    warm-up over --warmup-epochs, the full rate until ``held_epochs`` have passed (a run with
    --minutes holds its first, timed epoch: :class:`RunLength`), then constant or a cosine
    decay reaching 0 after the last step of the run's epochs. A pure function of the step:
    resume gives the same rates."""
    warm = round(config.warmup_epochs * steps_per_epoch)
    if step < warm:
        return config.lr * (step + 1) / warm
    hold = max(warm, held_epochs * steps_per_epoch)
    if config.schedule == "constant" or step < hold:
        return config.lr
    total = max(config.epochs * steps_per_epoch - hold, 1)
    return config.lr * 0.5 * (1.0 + math.cos(math.pi * min(step - hold, total) / total))


def run_config(config: TrainConfig, source, train_ids, test_ids, resolution, vgg_sha256, params) -> dict:
    identity = run_identity(config, source.identity, resolution, vgg_sha256)
    return {
        "format": "shaderball-neural-run",
        "version": 1,
        "identity": identity,
        "identity_digest": digest(identity),
        "options": config.to_dict(),  # the fields a run file holds (not `benchmark`)
        "dataset_path": os.path.abspath(config.dataset),
        # what the dataset holds, whatever folder holds it: evaluate finds the run's dataset by it
        "dataset_content": getattr(source, "content", None) or {},
        "split": {"train": train_ids, "test": test_ids},
        "network": {
            "name": "NeuralRenderer (KT et al. 2019)",
            "resolution": resolution,
            "width": config.width,
            "parameters": params,
            "light_input": "(3 d_x, 3 d_y, 3 d_z, turbidity) from the record's lighting_vector",
        },
        "tonemap": {"name": "reinhard+srgb", "exposure": config.exposure},
        "optimizer": {
            "name": "Adam",
            "lr": config.lr,
            "betas": [0.9, 0.999],
            "schedule": config.schedule,
            "warmup_epochs": config.warmup_epochs,
        },
        "torch": torch.__version__,
    }


def train(config: TrainConfig, progress=None, source=None) -> TrainSummary:
    """Train (or resume) a run; ``progress(dict)`` is called after every batch.

    ``source`` is the opened dataset (:func:`pipeline.neural.data.open_dataset`); by
    default ``config.dataset`` is opened. Nothing is written before every check passed.
    ``config.threads`` holds for the call; torch's setting is restored after.
    """
    started = time.perf_counter()  # --minutes counts from here
    config.check_run(dataset_opened=source is not None)
    device = pick_device(config.device)
    config = dataclasses.replace(config, precision=speed.resolve_precision(config.precision, device))
    if config.devices > 1:
        return train_distributed(config, progress, source, device, _train)
    with speed.torch_threads(config.threads):
        return _train(config, progress, source, device, started=started)


@dataclass
class _Setup:
    """What a run is, found (and checked) before anything is written."""

    config: TrainConfig  # with the loss chosen (``auto`` resolved)
    source: object  # the opened dataset
    split: RunSplit
    inputs: InputPlan  # what the network takes beyond the maps and the lighting vector
    choice: LossChoice
    loss_fn: RenderLoss
    model: NeuralRenderer
    fresh: dict  # the run's config.json
    old: dict | None  # the folder's config.json when it continues a run


def _train(config: TrainConfig, progress, source, device, ranks=None, started=None) -> TrainSummary:
    """The run in this process; ``ranks`` (pipeline.neural.distributed.Ranks) when it is one of
    several: then only its rank 0 scores the epochs and writes files. ``started``: when the
    call began (``time.perf_counter()``), which --minutes counts from."""
    run = _set_up(config, progress, source)
    config, model = run.config, run.model
    ckpt = _resume_point(run)
    length = RunLength.of(config, ckpt, started, progress)
    if ckpt is not None and int(ckpt["epoch"]) >= length.epochs:
        return _finished(config, run.old, ckpt, device, model, run.choice)
    config = dataclasses.replace(config, epochs=length.epochs)
    if ranks is not None:
        ranks.barrier()  # every rank has read the run folder before rank 0 writes in it
        model = run.model = ranks.sync_batchnorm(model)
    model.to(device)
    run.loss_fn.to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr, betas=(0.9, 0.999))
    forward = speed.step_forward(model, run.loss_fn, config.channels_last, config.compile)
    start_epoch, history = 0, []
    if ckpt is not None:
        _resume_state(config.out, model, optimizer, ckpt)
        start_epoch, history = ckpt["epoch"], list(ckpt["history"])
    if ranks is not None:
        forward = ranks.wrap(model, config.compile)
    record = run.split.record()
    train_set = with_inputs(split_samples(run.source, record, "train"), run.inputs)
    test_set = with_inputs(split_samples(run.source, record, "test"), run.inputs) if run.split.test else None
    train_probe = training_probe(train_set, config.splitting_seed)
    if ranks is None or ranks.main:
        _write_run_config(run, train_set, test_set)
    steps = math.ceil(len(train_set) / config.batch_size)
    clock = StepClock(steps * (config.epochs - start_epoch), config.epochs - start_epoch, steps)
    run_clock = RunClock(time.perf_counter() if started is None else started, start_epoch)
    epoch, step = start_epoch, (model, run.loss_fn, optimizer, train_set, device)
    with deterministic_algorithms():
        while epoch < config.epochs:
            epoch += 1
            epoch_started = time.perf_counter()
            entry = train_epoch(*step, config, epoch, progress, forward, clock, ranks, length.held_epochs)
            if ranks is not None and not ranks.main:
                history.append(entry)
                continue
            scoring_started = time.perf_counter()
            _score_epoch(entry, run, device, train_probe, test_set)
            score_s = time.perf_counter() - scoring_started
            if length.budgeted:  # a run with --minutes: its length from the epochs' times
                config = dataclasses.replace(config, epochs=length.after_epoch(epoch, epoch_started, progress))
            if length.held_epochs:
                entry["schedule_epochs"] = config.epochs
            _record_epoch(entry, history, config, progress)
            _save_epoch(config.out, model, optimizer, history, run.fresh["identity_digest"])
            run_clock.after_epoch(epoch, config.epochs, entry["time_s"], score_s, epoch_started, progress)
    return TrainSummary(
        run_dir=config.out,
        epochs_done=max(start_epoch, config.epochs if history else 0),
        resumed_from=start_epoch,
        history=history,
        baseline_psnr=(run.fresh.get("baseline") or {}).get("test_psnr"),  # rank 0's alone has one
        device=str(device),
        parameters=parameter_count(model),
        loss=run.choice.name,
        loss_reason=run.choice.reason,
        estimated_seconds=run_clock.seconds,
        estimate=run_clock.text,
        length_note=length.note,
        precision=config.precision,
        threads=torch.get_num_threads(),
    )


def _record_epoch(entry: dict, history: list[dict], config: TrainConfig, progress) -> None:
    """The epoch's warnings (logged, told to ``progress``), then the epoch, into ``history``."""
    entry["warnings"] = epoch_warnings(entry, history[-1] if history else None)
    for text in entry["warnings"]:
        log.warning("%s", text)
        if progress is not None:
            progress({"epoch": entry["epoch"], "epochs": config.epochs, "warning": text})
    history.append(entry)


def _set_up(config: TrainConfig, progress, source) -> _Setup:
    """The dataset (``source``, else ``config.dataset`` opened) split by material, the loss
    (said to ``progress``), the network initialised from the seed, the run's config.json."""
    config_path = os.path.join(config.out, runfiles.CONFIG)
    old = runfiles.read_config(config.out) if os.path.isfile(config_path) else None
    # the loss (and its refusals) before the data is read
    choice = choose_loss(config, (old or {}).get("identity", {}).get("loss") if config.loss == "auto" else None)
    if source is None:
        source = open_dataset(
            config.dataset, resolution=config.resolution, exposure=config.exposure, check_hashes=config.hash_check
        )
    split = run_split(config, source)
    inputs = InputPlan.for_run(config, source, split.train)
    requested = config.loss
    config = dataclasses.replace(config, loss=choice.name)
    loss_fn, vgg_sha = make_loss(choice, config.vgg_weight)
    torch.manual_seed(config.seed)
    network = {"resolution": source.resolution, "width": config.width, **inputs.network_record()}
    model = network_from_config(network)
    fresh = run_config(config, source, split.train, split.test, source.resolution, vgg_sha, parameter_count(model))
    fresh["split"], fresh["network"] = split.record(), {**fresh["network"], **inputs.network_record()}
    fresh["loss"] = {"requested": requested, "used": choice.name, "reason": choice.reason}
    if progress is not None:
        progress({"note": choice.reason})
    return _Setup(config, source, split, inputs, choice, loss_fn, model, fresh, old)


def _resume_point(run: _Setup) -> dict | None:
    """The folder's last checkpoint when the run continues one (None: it starts afresh); a
    run of another configuration, or of more epochs than asked for, is refused."""
    config, old, fresh = run.config, run.old, run.fresh
    if old is None:
        return None
    if old["identity_digest"] != fresh["identity_digest"]:
        changed = sorted(
            k
            for k in set(old["identity"]) | set(fresh["identity"])
            if old["identity"].get(k) != fresh["identity"].get(k)
        )
        raise TrainConfig.field_error(
            "out",
            config.out,
            "a new {out} folder, or the same options",
            what=f"{quoted(config.out)} is a run of another configuration (differs in: {', '.join(changed)})",
        )
    fresh["baseline"] = old.get("baseline")
    if not os.path.isfile(os.path.join(config.out, runfiles.CHECKPOINT)):
        return None
    ckpt = runfiles.load_checkpoint(config.out, fresh["identity_digest"], network=run.model)
    done = int(ckpt["epoch"])
    if done > config.epochs:
        # Training "to" fewer epochs cannot undo epochs: refuse, and keep config.json's
        # options.epochs the run's (not rewritten, e.g. 2 -> 1).
        raise TrainConfig.field_error(
            "epochs",
            config.epochs,
            f"at least {done}: {quoted(config.out)} has already trained {done} epochs "
            f"(pass {{epochs}} {done} or more to continue it, or a new {{out}} to start again)",
        )
    return ckpt


def _write_run_config(run: _Setup, train_set, test_set) -> None:
    """config.json, with the baseline (the training-set mean image's held-out PSNR) found
    first by a fresh run: the first file written, after every sample has been read."""
    if not run.fresh.get("baseline"):
        workers = run.config.loader_workers
        mean_target = mean_image(train_set, workers)
        run.fresh["baseline"] = {
            "kind": "training-set mean image",
            "test_psnr": baseline_psnr(mean_target, test_set, workers),
        }
    os.makedirs(run.config.out, exist_ok=True)
    runfiles.write_json(os.path.join(run.config.out, runfiles.CONFIG), run.fresh, inside=run.config.out)


def _score_epoch(entry: dict, run: _Setup, device, train_probe, test_set) -> None:
    """The epoch's weights checked finite, then scored on the training probe and the held-out
    split (into ``entry``)."""
    model, config = run.model, run.config
    bad = run_checks.nonfinite_weights(model.state_dict())
    if bad:
        raise diverged(f"{bad:,} weight value(s) are NaN or infinite", entry["epoch"], entry["lr"])
    if train_probe is not None:
        seen = evaluate_split(model, run.loss_fn, train_probe, device, config.batch_size, config.loader_workers)
        entry.update(train_eval_loss=seen["loss"], train_psnr=seen["psnr"])
    if test_set is not None:
        held_out = evaluate_split(model, run.loss_fn, test_set, device, config.batch_size, config.loader_workers)
        entry.update(test_loss=held_out["loss"], test_psnr=held_out["psnr"], test_saturated=held_out["saturated"])


def _save_epoch(run_dir: str, model, optimizer, history: list[dict], identity_digest: str) -> None:
    """The epoch's checkpoint (and the best one's), log.jsonl, log.csv and loss.png."""
    state = dict(
        epoch=history[-1]["epoch"],
        model_state=model.state_dict(),
        optimizer_state=optimizer.state_dict(),
        history=history,
        identity_digest=identity_digest,
    )
    if is_best(history):  # before the last: a kill between them redoes this epoch, same weights
        best = dict(state, optimizer_state=None)  # the weights only: resume uses the last
        runfiles.save_checkpoint(run_dir, name=runfiles.BEST_CHECKPOINT, **best)
    runfiles.save_checkpoint(run_dir, **state)
    runfiles.write_log(os.path.join(run_dir, runfiles.LOG), history, inside=run_dir)
    runfiles.write_log_csv(os.path.join(run_dir, runfiles.LOG_CSV), history, inside=run_dir)
    write_bytes_atomic(os.path.join(run_dir, runfiles.LOSS_PNG), loss_curve_png(history), inside=run_dir)


def _resume_state(run_dir: str, model, optimizer, ckpt: dict) -> None:
    """The checkpoint's weights and optimiser state, or a ShaderballError naming what does not fit."""
    path = os.path.join(run_dir, runfiles.CHECKPOINT)
    if "optimizer" not in ckpt:
        raise ShaderballError(
            f"{path}: holds the weights only (no optimizer state), so the run cannot continue from it; "
            "restore the run's last checkpoint or train a new --out"
        )
    problem = run_checks.optimizer_problem(ckpt["optimizer"], optimizer.state_dict())
    if problem:
        raise ShaderballError(
            f"{path}: a corrupt checkpoint: {problem}; restore it, or remove it to train again from the start"
        )
    try:
        model.load_state_dict(ckpt["model"])
    except RuntimeError as exc:
        raise runfiles.weights_mismatch(exc, path, "last", os.path.join(run_dir, runfiles.CONFIG)) from None
    try:
        optimizer.load_state_dict(ckpt["optimizer"])
    except (ValueError, KeyError, TypeError, RuntimeError) as exc:
        raise ShaderballError(
            f"{path}: a corrupt checkpoint: its optimizer state does not fit the network ({type(exc).__name__}: "
            f"{str(exc)[:200]}); restore it, or remove it to train again from the start"
        ) from None


def training_probe(train_set, seed: int):
    """A fixed sample of at most TRAIN_EVAL_SAMPLES training renders, scored in eval mode
    after every epoch as the held-out split is (the learning curve's training PSNR)."""
    if len(train_set) == 0:
        return None
    order = np.random.default_rng(np.random.SeedSequence([int(seed), SUBSET_STREAM, 1])).permutation(len(train_set))
    return Subset(train_set, sorted(order[:TRAIN_EVAL_SAMPLES].tolist()))


def is_best(history: list[dict]) -> bool:
    """Whether the last epoch has the best held-out PSNR so far (the first of equals)."""
    psnrs = [h.get("test_psnr") for h in history]
    if psnrs[-1] is None:
        return False
    return all(p is None or p < psnrs[-1] for p in psnrs[:-1])


def _finished(config: TrainConfig, old_config: dict, ckpt: dict, device, model, choice: LossChoice) -> TrainSummary:
    """A run that already has ``config.epochs`` epochs: nothing to train, nothing written."""
    history = list(ckpt["history"])
    return TrainSummary(
        run_dir=config.out,
        epochs_done=int(ckpt["epoch"]),
        resumed_from=int(ckpt["epoch"]),
        history=history,
        baseline_psnr=(old_config.get("baseline") or {}).get("test_psnr"),
        device=str(device),
        parameters=parameter_count(model),
        nothing_to_do=True,
        loss=choice.name,
        loss_reason=choice.reason,
    )


def train_epoch(
    model,
    loss_fn,
    optimizer,
    train_set,
    device,
    config: TrainConfig,
    epoch: int,
    progress,
    forward=None,
    clock=None,
    ranks=None,
    held_epochs: int = 0,
) -> dict:
    """One epoch; ``forward`` runs the network (default ``model``; compiled: speed.step_forward) in
    ``config.precision``; ``clock`` (:class:`StepClock`) is told of every step, its estimate goes to
    ``progress``; with ``ranks`` (:class:`pipeline.neural.distributed.Ranks`) losses are the batch's."""
    forward = forward or model
    scaler = speed.grad_scaler(device, config.precision)
    model.train()
    loss_fn.train()
    order, batch_size = epoch_order(len(train_set), config.seed, epoch), config.batch_size
    if ranks is not None:  # this rank's part of every batch
        order, batch_size = ranks.shard(order), batch_size // ranks.world
    loader = batches(Subset(train_set, order), batch_size, config.loader_workers, pin_memory=device.type == "cuda")
    count, lr = len(loader), config.lr
    sums: dict[str, float] = {}
    seen, started = 0, time.perf_counter()
    for index, batch in enumerate(loader, start=1):
        maps, light, target = batch_to(batch, device, config.channels_last)
        lr = learning_rate(config, (epoch - 1) * count + index - 1, count, held_epochs)
        for group in optimizer.param_groups:
            group["lr"] = lr
        optimizer.zero_grad(set_to_none=True)
        with speed.autocast(device, config.precision):
            parts = loss_fn.parts(forward(maps, light, *batch_extra(batch, device)), target)
        scaler.scale(parts["total"]).backward()
        scaler.step(optimizer)
        scaler.update()
        loss = float(parts["total"].detach())  # after the step, as before: no sync of its own
        n = maps.shape[0]
        means = {key: float(value.detach()) for key, value in parts.items()}
        if ranks is not None:  # the whole batch's, every rank's summed
            means, n = ranks.batch_means(means, n)
            loss = means["total"]
        if not math.isfinite(loss):  # the weights in memory are spoilt; none is saved
            raise diverged(f"batch {index} of {count}: the training loss is {loss}", epoch, lr)
        seen += n
        for key, value in means.items():
            sums[key] = sums.get(key, 0.0) + value * n
        estimate = clock.tick() if clock is not None else None
        if estimate is not None and progress is not None:
            progress({"note": estimate})
        if progress is not None:
            elapsed = time.perf_counter() - started
            rate = seen / elapsed if elapsed > 0 else 0.0
            left = (count - index) * config.batch_size + (config.epochs - epoch) * len(train_set)
            progress(
                {
                    "epoch": epoch,
                    "epochs": config.epochs,
                    "batch": index,
                    "batches": count,
                    "loss": loss,
                    "samples_per_s": rate,
                    "eta_s": left / rate if rate > 0 else None,
                }
            )
    elapsed = time.perf_counter() - started
    entry = {
        "epoch": epoch,
        "train_loss": sums["total"] / seen,
        "train_l1": sums["l1"] / seen,
        "time_s": elapsed,
        "samples_per_s": seen / elapsed if elapsed > 0 else None,
        "lr": lr,
    }
    entry.update({f"train_{key}": sums[key] / seen for key in ("vgg", "l2") if key in sums})
    return entry
