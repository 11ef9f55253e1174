"""The loss curve of a run as a PNG (PIL only: no plotting library is a dependency)."""

from __future__ import annotations

import io
import math

from PIL import Image, ImageDraw, ImageFont

SERIES = (("train_loss", "train loss", (31, 119, 180)), ("test_loss", "held-out loss", (214, 39, 40)))


def _nice_ticks(lo: float, hi: float, n: int = 5) -> list[float]:
    if hi <= lo:
        return [lo]
    step = 10 ** math.floor(math.log10((hi - lo) / n))
    for mult in (1, 2, 5, 10):
        if (hi - lo) / (step * mult) <= n:
            step *= mult
            break
    start = math.ceil(lo / step) * step
    return [start + i * step for i in range(int((hi - start) / step) + 1)]


def loss_curve_png(history: list[dict], width: int = 640, height: int = 400) -> bytes:
    """PNG bytes: per-epoch training and held-out loss against the epoch, log10 y axis."""
    img = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(img)
    font = ImageFont.load_default()
    left, right, top, bottom = 70, 20, 30, 45
    x0, x1, y0, y1 = left, width - right, top, height - bottom
    draw.rectangle([x0, y0, x1, y1], outline="black")
    draw.text((x0, 8), "loss per epoch (log scale)", fill="black", font=font)
    draw.text(((x0 + x1) // 2 - 15, height - 18), "epoch", fill="black", font=font)
    points = {
        key: [(h["epoch"], h[key]) for h in history if h.get(key) is not None and h[key] > 0] for key, _, _ in SERIES
    }
    values = [v for pts in points.values() for _, v in pts]
    if not values:
        draw.text((x0 + 10, y0 + 10), "no finished epoch yet", fill="black", font=font)
    else:
        epochs = [e for pts in points.values() for e, _ in pts]
        e_lo, e_hi = min(epochs), max(max(epochs), min(epochs) + 1)
        l_lo, l_hi = math.log10(min(values)), math.log10(max(values))
        if l_hi - l_lo < 0.1:
            l_lo, l_hi = l_lo - 0.05, l_hi + 0.05

        def xy(epoch, value):
            x = x0 + (epoch - e_lo) / (e_hi - e_lo) * (x1 - x0)
            y = y1 - (math.log10(value) - l_lo) / (l_hi - l_lo) * (y1 - y0)
            return x, y

        for t in _nice_ticks(l_lo, l_hi):
            _, y = xy(e_lo, 10**t)
            draw.line([x0 - 4, y, x0, y], fill="black")
            draw.text((5, y - 6), f"{10**t:.3g}", fill="black", font=font)
        for t in _nice_ticks(e_lo, e_hi):
            if float(t).is_integer():
                x, _ = xy(t, 10**l_lo)
                draw.line([x, y1, x, y1 + 4], fill="black")
                draw.text((x - 4, y1 + 6), str(int(t)), fill="black", font=font)
        for i, (key, label, colour) in enumerate(SERIES):
            pts = [xy(e, v) for e, v in points[key]]
            if len(pts) > 1:
                draw.line(pts, fill=colour, width=2)
            for x, y in pts:
                draw.ellipse([x - 3, y - 3, x + 3, y + 3], fill=colour)
            draw.line([x1 - 150, y0 + 12 + 14 * i, x1 - 130, y0 + 12 + 14 * i], fill=colour, width=2)
            draw.text((x1 - 125, y0 + 6 + 14 * i), label, fill="black", font=font)
    out = io.BytesIO()
    img.save(out, format="PNG")
    return out.getvalue()
