"""How long a training run is and takes: its epochs, with ``--minutes`` fitted to the time
left after each epoch (:class:`RunLength`), the estimate from a call's first steps
(:class:`StepClock`), and the whole run's estimate and ETA after each epoch (:class:`RunClock`)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

from pipeline.neural.config import TrainConfig

#: Steps timed after the first (which starts the loader and warms up) before a run says how
#: long it will take; a first epoch of fewer steps is timed whole.
ESTIMATE_STEPS = 5


@dataclass
class RunLength:
    """How many epochs a run has: ``--epochs``, or, with ``--minutes``, as many (at most
    ``--epochs``) as fit the time from the call's start: set after the first epoch from its time
    (training and scoring), then shortened after any epoch whose mean time so far says the rest
    would not fit (never lengthened). Each epoch of the history records it
    (``schedule_epochs``), and a resumed run keeps the last, with or without --minutes. Such a
    run holds the learning rate through the first epoch (``held_epochs``): a cosine then decays
    over the epochs after it, which are only known once it is timed."""

    epochs: int
    held_epochs: int = 0  # epochs at the full rate before the schedule (1 with --minutes)
    minutes: float | None = None  # the budget, in the call that started the run
    started: float = 0.0  # time.perf_counter() when that call began
    note: str | None = None
    times: list[float] = field(default_factory=list)  # each epoch's seconds, scoring and saving included
    mark: float | None = None  # when the last epoch's time was taken

    @property
    def budgeted(self) -> bool:
        return self.minutes is not None

    @classmethod
    def of(cls, config: TrainConfig, ckpt: dict | None, started: float | None, progress=None) -> RunLength:
        history = (ckpt or {}).get("history") or []
        recorded = history[-1].get("schedule_epochs") if history else None
        if recorded is not None:  # at most --epochs: a constant schedule's run may be cut short
            return cls(min(recorded, config.epochs), held_epochs=1)
        if config.minutes is None:
            return cls(config.epochs)
        if history:
            note = f"--minutes {config.minutes:g} not used: the run started without it and trains to --epochs"
            if progress is not None:
                progress({"note": note})
            return cls(config.epochs, note=note)
        begun = time.perf_counter() if started is None else started
        return cls(config.epochs, held_epochs=1, minutes=config.minutes, started=begun)

    def after_epoch(self, epoch: int, epoch_started: float, progress=None) -> int:
        """The run's length after ``epoch`` (the first begun at ``epoch_started``; each later one
        timed from the last's call, so its saving counts), said to ``progress`` when it is set or
        shortened."""
        now = time.perf_counter()
        self.times.append(now - (epoch_started if self.mark is None else self.mark))
        self.mark = now
        left_s, per_epoch = self.minutes * 60 - (now - self.started), sum(self.times) / len(self.times)
        fits = budget_epochs(left_s, per_epoch, self.epochs, done=epoch)
        if len(self.times) > 1 and fits >= self.epochs:
            return self.epochs
        was, self.epochs = self.epochs, fits
        plural = "s" if fits != 1 else ""
        if len(self.times) == 1:
            self.note = (
                f"--minutes {self.minutes:g}: the first epoch took {per_epoch:.0f} s with its scoring, "
                f"{max(left_s, 0) / 60:.1f} min are left: the run is {fits} epoch{plural}"
            )
        else:
            self.note = (
                f"--minutes {self.minutes:g}: {per_epoch:.0f} s an epoch so far, {max(left_s, 0) / 60:.1f} min "
                f"left after epoch {epoch}: the run is {fits} epoch{plural} (was {was})"
            )
        if progress is not None:
            progress({"note": self.note})
        return self.epochs


def budget_epochs(left_s: float, epoch_s: float, most: int, done: int = 1) -> int:
    """Epochs of a run that has ``done`` epochs of ``epoch_s`` seconds each with ``left_s``
    seconds left: those and as many more as fit, at most ``most`` (and at least ``done``)."""
    more = math.floor(left_s / epoch_s) if epoch_s > 0 else most
    return max(done, min(most, done + more))


class StepClock:
    """How long a call's ``steps`` training steps (``epochs`` epochs of ``per_epoch``) will
    take, from its first ones: the first step (the loader started, the first batch read,
    kernels chosen) is left out and the next ESTIMATE_STEPS are timed, or the rest of the
    first epoch when it has fewer. Told once (:meth:`tick`'s line); then ``seconds``."""

    def __init__(self, steps: int, epochs: int, per_epoch: int):
        self.steps, self.epochs, self.per_epoch = steps, epochs, per_epoch
        self.times = [time.perf_counter()]
        self.seconds: float | None = None
        self.text: str | None = None

    def tick(self) -> str | None:
        """Called after each step: the estimate's line when it is made, else None."""
        if self.text is not None:
            return None
        self.times.append(time.perf_counter())
        done = len(self.times) - 1
        if done < min(1 + ESTIMATE_STEPS, self.per_epoch):
            return None
        first = 1 if done > 1 else 0
        per_step = (self.times[-1] - self.times[first]) / (done - first)
        self.seconds = per_step * self.steps
        self.text = (
            f"training steps: about {_duration(self.seconds)} for {self.epochs} epoch{'s' if self.epochs != 1 else ''} "
            f"({per_step:.3g} s a step x {self.steps:,} steps; the estimate with the held-out scoring follows the "
            "first epoch)"
        )
        return self.text


def run_estimate(train_s: float, score_s: float, epochs: int) -> tuple[float, str]:
    """The seconds of ``epochs`` epochs that each train for ``train_s`` and score for ``score_s``
    (the training and held-out probes after the epoch), and the line that says so."""
    seconds = (train_s + score_s) * epochs
    return seconds, (
        f"estimate: about {_duration(seconds)} for {epochs} epoch{'s' if epochs != 1 else ''} "
        f"({train_s:.3g} s training + {score_s:.3g} s scoring an epoch, measured on the first)"
    )


@dataclass
class RunClock:
    """The whole of a call's run: after its first epoch, the estimate from that epoch's training
    and scoring times and the run's length (--minutes' epochs once the budget set them); after
    every epoch, the epochs done, the time so far and an ETA from the epochs measured (each
    timed whole, saving included). Each line goes to ``progress`` as a note."""

    started: float  # when the call began (time.perf_counter())
    first_epoch: int  # epochs done when the call began
    times: list[float] = field(default_factory=list)
    seconds: float | None = None
    text: str | None = None

    def after_epoch(self, epoch: int, epochs: int, train_s: float, score_s: float, epoch_started: float, progress):
        now = time.perf_counter()
        self.times.append(now - epoch_started)
        if self.text is None:
            self.seconds, self.text = run_estimate(train_s, score_s, epochs - self.first_epoch)
            if progress is not None:
                progress({"note": self.text, "estimate_s": self.seconds, "train_s": train_s, "score_s": score_s})
        elapsed, eta = now - self.started, sum(self.times) / len(self.times) * (epochs - epoch)
        if progress is not None:
            progress(
                {
                    "note": f"epoch {epoch}/{epochs} done: {_duration(elapsed)} so far, "
                    + (f"ETA {_duration(eta)}" if epoch < epochs else "the run is complete"),
                    "elapsed_s": elapsed,
                    "eta_s": eta,
                }
            )


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{max(seconds, 1):.0f} s"
    return f"{seconds / 60:.1f} min" if seconds < 5400 else f"{seconds / 3600:.1f} h"
