"""`shaderball study`'s request: the pixel study's (:class:`pipeline.study.request.StudyRequest`)
with ``--downstream`` and how each network trains, a part declared from `train`'s own fields.

The downstream study reads the pixel study's fields in the same sense: ``--ladder`` (spp of the
builds; the spec's own always added), ``--repeats`` (independent training seeds per level),
``--reference-spp`` (the held-out samples' references, two halves), ``--resolution`` (the
builds' and the networks'), ``--flip``. ``--draws`` and ``--configs``/``--only`` choose the
pixel study's samples and recipes and are refused with ``--downstream``; the training options
are refused without it.
"""

from __future__ import annotations

from dataclasses import dataclass

from pipeline.fields import Checked, field, part, same_as
from pipeline.fields.rules import Bool, Reject, StrList
from pipeline.neural.config import NetworkResolution, TrainConfig
from pipeline.neural.limits import LOSS_CHOICES
from pipeline.study.configs import FAMILIES
from pipeline.study.request import StudyRequest

#: The losses a downstream study trains with (train's, less ``auto``: a study names its loss).
STUDY_LOSSES = tuple(name for name in LOSS_CHOICES if name != "auto")


class Losses(StrList):
    """Losses, comma-separated, once each and in the order given (at least one)."""

    def __init__(self):
        super().__init__(STUDY_LOSSES, "losses")

    def check(self, value):
        value = super().check(value)
        if not value:
            raise Reject("(none given)")
        return value


@dataclass(frozen=True)
class NetworkTraining(Checked):
    """How each network of a downstream study trains: `train`'s options of the same names."""

    epochs: int = same_as(TrainConfig, "epochs", doc="Epochs each network trains (with {downstream}).")
    losses: tuple[str, ...] = field(
        ("l1", "l2"),
        rule=Losses(),
        doc="Training losses (with {downstream}), each on the tone-mapped sRGB targets: the first is trained at "
        "every level, the others at the spec's level and at the cheapest level the first passes.",
    )
    width: float = same_as(TrainConfig, "width")
    batch_size: int = same_as(TrainConfig, "batch_size")
    schedule: str = same_as(TrainConfig, "schedule")
    test_fraction: float = same_as(TrainConfig, "test_fraction")


@dataclass(frozen=True)
class StudyCommandRequest(StudyRequest):
    """What `shaderball study` is asked: pixels (the default) or, with ``downstream``, networks."""

    downstream: bool = field(
        False,
        rule=Bool(),
        doc="Measure the network instead of pixels: the spec's samples built at each spp of {ladder} and the "
        "spec's own, networks trained on each with {repeats} seeds, scored against references of the held-out "
        "samples (docs/accuracy.md).",
    )
    training: NetworkTraining = part(NetworkTraining, doc="How each network trains (with {downstream}).")

    def unused(self) -> tuple[str, ...]:
        """The fields this request's mode does not read (its command line leaves them out)."""
        if self.downstream:
            return ("scan", "draws", "configs", "only")
        return ("scan", "downstream", "epochs", "losses", "width", "batch_size", "schedule", "test_fraction")

    def check_cross(self) -> None:
        super().check_cross()
        if not self.downstream:
            default = NetworkTraining()
            for name in ("epochs", "losses", "width", "batch_size", "schedule", "test_fraction"):
                if getattr(self.training, name) != getattr(default, name):
                    raise self.field_error(
                        name, getattr(self.training, name), "its default, or give {downstream}", what="trains networks"
                    )
            return
        if self.training.test_fraction == 0:
            raise self.field_error(
                "test_fraction", 0.0, "above 0 with {downstream} (the networks are scored on held-out materials)"
            )
        if self.draws != StudyRequest.draws:
            raise self.field_error(
                "draws", self.draws, "its default with {downstream} (it scores every held-out sample)"
            )
        if self.only is not None:
            raise self.field_error("only", self.only, "unset with {downstream} (it studies one recipe, the spec's)")
        if tuple(self.configs) != FAMILIES:
            raise self.field_error("configs", self.configs, "all with {downstream} (it studies one recipe, the spec's)")
        if self.resolution is not None:
            try:
                NetworkResolution().check(self.resolution)
            except Reject:
                raise self.field_error(
                    "resolution",
                    self.resolution,
                    "a multiple of 16 from 16 to 4096 with {downstream} (the networks train at it)",
                ) from None
