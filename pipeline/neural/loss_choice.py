"""The loss a run trains with: ``--loss auto`` resolved (the run's own loss when it resumes
one, the paper's L1 + VGG16 when its weights are found, else L1) and made."""

from __future__ import annotations

import os
from dataclasses import dataclass

from pipeline.errors import ShaderballError
from pipeline.neural.config import TrainConfig
from pipeline.neural.loss import RenderLoss
from pipeline.neural.vgg import HUB_FILENAME, VggWeights, find_vgg_weights, hub_cache_path, load_vgg16_relu3_3


@dataclass(frozen=True)
class LossChoice:
    """The loss a run trains with and why (``--loss auto`` resolved)."""

    name: str  # l1+vgg, l1 or l2
    reason: str  # one line for the summary, the log and config.json
    weights: VggWeights | None  # the VGG16 weights (l1+vgg), their SHA-256 checked


def choose_loss(config: TrainConfig, run_loss: str | None = None) -> LossChoice:
    """``config.loss``, with ``auto`` resolved: the run's own loss when it resumes one
    (``run_loss``), the paper's l1+vgg when --vgg-weights is given or the weights are in torch
    hub's cache, else l1. An explicit l1+vgg without usable weights is refused (ShaderballError)."""
    if config.loss in ("l1", "l2"):
        return LossChoice(config.loss, f"loss: {config.loss} (--loss {config.loss})", None)
    if config.loss == "l1+vgg" or config.vgg_weights is not None or run_loss == "l1+vgg":
        weights = find_vgg_weights(config.vgg_weights, config.vgg_sha256)
        why = (
            "--loss l1+vgg"
            if config.loss == "l1+vgg"
            else ("the run's own loss" if run_loss == "l1+vgg" else "--loss auto, --vgg-weights given")
        )
        return LossChoice("l1+vgg", f"loss: l1+vgg, the paper's L1 + VGG16 ({why}; weights {weights.path})", weights)
    if run_loss in ("l1", "l2"):
        return LossChoice(run_loss, f"loss: {run_loss} (--loss auto: the run's own loss)", None)
    try:
        weights = find_vgg_weights(None, config.vgg_sha256)
    except ShaderballError as exc:
        found = os.path.isfile(hub_cache_path())
        why = (getattr(exc, "what", None) or str(exc)) if found else f"no VGG16 ImageNet weights at {hub_cache_path()}"
        return LossChoice(
            "l1",
            f"loss: l1 (--loss auto: {why}; for the paper's L1 + VGG16 put {HUB_FILENAME} there or pass "
            "--vgg-weights FILE)",
            None,
        )
    return LossChoice(
        "l1+vgg", f"loss: l1+vgg, the paper's L1 + VGG16 (--loss auto: weights found at {weights.path})", weights
    )


def make_loss(choice: LossChoice, vgg_weight: float) -> tuple[RenderLoss, str | None]:
    if choice.name in ("l1", "l2"):
        return RenderLoss(choice.name), None
    return RenderLoss("l1+vgg", load_vgg16_relu3_3(choice.weights), vgg_weight), choice.weights.sha256
