"""The paper's training loss (section 4.3): L1 plus a VGG16 relu3_3 feature
reconstruction term (mean squared feature difference), or L1 alone, or L2 alone.

Every loss is taken on the network's images: the tone-mapped, sRGB-encoded targets in [0, 1]
(pipeline.image.tonemap), not linear HDR radiance. L2's minimiser is the mean of a target's
noise in that space, L1's its median: neither is the tone map of the mean radiance, so a
network trained on noisy targets may be biased (`shaderball study --downstream` measures it)."""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from pipeline.neural.config import TrainConfig
from pipeline.neural.vgg import IMAGENET_MEAN, IMAGENET_STD

LOSSES = ("l1+vgg", "l1", "l2")


class RenderLoss(nn.Module):
    """``l1 + vgg_weight * mse(relu3_3(pred), relu3_3(target))`` on images in [0, 1]
    (``l1``: the first term alone; ``l2``: the mean squared difference alone).

    The images are the network's tone-mapped sRGB-encoded targets, which is what VGG16's
    ImageNet inputs were, and are normalised with ImageNet's mean and std before VGG.
    The VGG stays frozen and in eval mode whatever ``train()`` is called on this module.
    """

    def __init__(self, kind: str, vgg: nn.Module | None = None, vgg_weight: float = 1.0):
        super().__init__()
        if kind not in LOSSES:
            raise TrainConfig.field_error("loss", kind, " or ".join(LOSSES))
        if (kind == "l1+vgg") != (vgg is not None):
            raise ValueError("the l1+vgg loss needs a VGG, the l1 and l2 losses none")
        self.kind = kind
        self.vgg = vgg
        self.vgg_weight = float(vgg_weight)
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    def train(self, mode: bool = True):
        super().train(mode)
        if self.vgg is not None:
            self.vgg.eval()
        return self

    def parts(self, pred: torch.Tensor, target: torch.Tensor) -> dict[str, torch.Tensor]:
        if self.kind == "l2":
            l2 = F.mse_loss(pred, target)
            return {"l1": F.l1_loss(pred.detach(), target), "l2": l2, "total": l2}  # l1: the log's figure
        out = {"l1": F.l1_loss(pred, target)}
        if self.vgg is not None:
            f_pred = self.vgg((pred - self.mean) / self.std)
            with torch.no_grad():
                f_target = self.vgg((target - self.mean) / self.std)
            out["vgg"] = F.mse_loss(f_pred, f_target)
            out["total"] = out["l1"] + self.vgg_weight * out["vgg"]
        else:
            out["total"] = out["l1"]
        return out

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        return self.parts(pred, target)["total"]
