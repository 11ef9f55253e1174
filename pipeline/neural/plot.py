"""A run's curves as PNG (PIL only: no plotting library is a dependency): the loss per
epoch (``loss.png``), the learning curve of a report (loss and PSNR per epoch, training and
held-out, beside the mean-image baseline) and the data-size curve of a sweep."""

from __future__ import annotations

from pipeline.image.chart import BLUE, GREEN, GREY, ORANGE, PURPLE, RED, chart, png

__all__ = ["BLUE", "GREEN", "GREY", "ORANGE", "PURPLE", "RED", "chart", "png"]

SERIES = (("train_loss", "train loss", BLUE), ("test_loss", "held-out loss", RED))


def loss_curve_png(history: list[dict], width: int = 640, height: int = 400) -> bytes:
    """PNG bytes: per-epoch training and held-out loss against the epoch, log10 y axis."""
    series = [(label, colour, [(h["epoch"], h.get(key)) for h in history]) for key, label, colour in SERIES]
    return png(chart(series, "loss per epoch (log scale)", "epoch", log_y=True, width=width, height=height))


def learning_curve_png(history: list[dict], baseline_psnr: float | None = None) -> bytes:
    """Two panels: loss (training loop, training sample in eval mode, held-out) and 8-bit
    PSNR (training sample, held-out, the training set's mean image on held-out) per epoch."""
    epochs = [h["epoch"] for h in history]
    loss = [
        ("train loss (training loop)", BLUE, [(h["epoch"], h.get("train_loss")) for h in history]),
        ("train loss (eval mode)", GREEN, [(h["epoch"], h.get("train_eval_loss")) for h in history]),
        ("held-out loss", RED, [(h["epoch"], h.get("test_loss")) for h in history]),
    ]
    psnr = [
        ("train PSNR (eval mode)", GREEN, [(h["epoch"], h.get("train_psnr")) for h in history]),
        ("held-out PSNR", RED, [(h["epoch"], h.get("test_psnr")) for h in history]),
    ]
    if baseline_psnr is not None and epochs:
        psnr.append(("--mean image, held-out", GREY, [(min(epochs), baseline_psnr), (max(epochs), baseline_psnr)]))
    return png(
        chart(loss, "loss per epoch (log scale)", "epoch", log_y=True),
        chart(psnr, "PSNR per epoch (dB, 8-bit sRGB)", "epoch"),
    )
