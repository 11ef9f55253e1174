"""What `shaderball train` says of a run: its summary (:class:`TrainSummary`), the warnings
after an epoch that say it is not learning (saturated outputs, a held-out loss that does not
move), the advice when it ends below the training-set mean image, and the stop of a run whose
loss or weights stopped being finite (:class:`Diverged`)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from pipeline.errors import ShaderballError
from pipeline.neural import runfiles

#: A held-out output at 8-bit 0 or 255 is saturated; more than this fraction of them is a warning.
SATURATED_FRACTION = 0.99
#: A held-out loss whose relative change over an epoch is below this "does not move".
STALL_RELATIVE = 1e-5


@dataclass
class TrainSummary:
    run_dir: str
    epochs_done: int
    resumed_from: int  # epochs already done when this call started
    history: list[dict] = field(default_factory=list)
    baseline_psnr: float | None = None
    device: str = "cpu"
    parameters: int = 0
    nothing_to_do: bool = False  # the run already had --epochs epochs; nothing was written
    loss: str = ""  # the loss trained with: l1+vgg or l1
    loss_reason: str = ""  # one line: which loss, and why (--loss auto's choice)
    #: what to try when the held-out PSNR ends below the training-set mean image's; None otherwise
    below_mean_image: str | None = None
    #: the seconds this call's steps were estimated to take, from its first steps (StepClock), and
    #: the line that said so on stderr; None when it trained nothing
    estimated_seconds: float | None = None
    estimate: str | None = None
    #: how --minutes set the run's length (train prints it); None without --minutes
    length_note: str | None = None
    #: the precision and torch threads it trained with (--precision auto and --threads 0 made concrete)
    precision: str = ""
    threads: int = 0

    def __post_init__(self):
        if self.below_mean_image is None:
            self.below_mean_image = below_mean_image_advice(self.history, self.baseline_psnr)

    def to_dict(self) -> dict:
        return asdict(self)

    def lines(self) -> list[str]:
        # loss_reason is said once, before training (the progress' note), not again here
        how = f"{self.precision}, {self.threads} thread{'s' if self.threads != 1 else ''}, " if self.precision else ""
        out = [f"run: {self.run_dir} ({self.parameters:,} parameters, {self.device}, {how}loss {self.loss})"]
        if self.nothing_to_do:
            out.append(
                f"nothing to do: the run has already trained {self.epochs_done} epochs "
                "(pass a larger --epochs to continue it); nothing written"
            )
        elif self.resumed_from:
            out.append(f"resumed after epoch {self.resumed_from}")
        if self.length_note:
            out.append(self.length_note)
        if self.history:
            last = self.history[-1]
            out.append(
                f"epoch {last['epoch']}: train loss {last['train_loss']:.4f}"
                + (
                    f", held-out loss {last['test_loss']:.4f}, PSNR {last['test_psnr']:.2f} dB"
                    if last.get("test_loss") is not None
                    else ""
                )
            )
        if self.baseline_psnr is not None:
            out.append(f"baseline (training-set mean image) PSNR on held-out: {self.baseline_psnr:.2f} dB")
        if self.history and self.history[-1].get("warnings"):
            out.extend(f"warning: {text}" for text in self.history[-1]["warnings"])
        if self.below_mean_image:
            out.append(f"warning: {self.below_mean_image}")
        return out


def below_mean_image_advice(history: list[dict], baseline_psnr: float | None) -> str | None:
    """What to try when the last epoch's held-out PSNR is below the training-set mean image's
    (the run has not learnt more than the average picture); None when it is above, or unknown."""
    last = history[-1].get("test_psnr") if history else None
    if last is None or baseline_psnr is None or last >= baseline_psnr:
        return None
    epoch, lr = history[-1].get("epoch"), history[-1].get("lr")
    at = f" (now {lr:g})" if lr else ""
    return (
        f"held-out PSNR {last:.2f} dB after epoch {epoch} is below the training-set mean image's "
        f"{baseline_psnr:.2f} dB: the network predicts worse than the average picture. Try more epochs "
        f"(a larger --epochs continues this run), another --lr{at}: lower if the loss jumps about or the "
        "outputs saturate, higher if it falls slowly; or more training data (more materials)"
    )


def smaller_lr(lr: float | None) -> str:
    return f"a smaller --lr (e.g. --lr {lr / 10:g}; the released code's Adam uses 1e-3)" if lr else "a smaller --lr"


class Diverged(ShaderballError):
    """A run whose loss or weights stopped being finite: it stops, and saves nothing of the epoch."""


def diverged(what: str, epoch: int, lr: float) -> Diverged:
    kept = f"{runfiles.CHECKPOINT} keeps epoch {epoch - 1}" if epoch > 1 else "no checkpoint is written"
    return Diverged(
        f"epoch {epoch}: {what}: the run stops, nothing of epoch {epoch} is saved ({kept}). The dataset's samples "
        f"are checked as they load, so the optimiser diverged: train again with {smaller_lr(lr)} in a new --out"
    )


def epoch_warnings(entry: dict, previous: dict | None) -> list[str]:
    """What says a run is not learning after an epoch: saturated held-out outputs, or a
    held-out loss that did not move (the paper's lr 1e-2 does both)."""
    hint = "try " + smaller_lr(entry.get("lr"))
    out = []
    if entry.get("test_saturated") is not None and entry["test_saturated"] > SATURATED_FRACTION:
        out.append(
            f"epoch {entry['epoch']}: {100 * entry['test_saturated']:.1f}% of held-out output values are "
            f"saturated (0 or 1 after the tone map): the sigmoid has stopped passing gradients; {hint}"
        )
    if previous is not None and previous.get("test_loss") is not None and entry.get("test_loss") is not None:
        before, after = previous["test_loss"], entry["test_loss"]
        if abs(after - before) <= STALL_RELATIVE * max(abs(before), 1e-12):
            out.append(
                f"epoch {entry['epoch']}: the held-out loss did not move ({before:.6g} -> {after:.6g}, "
                f"less than {STALL_RELATIVE:.0e} relative); {hint}"
            )
    return out
