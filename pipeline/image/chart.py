"""Line charts as PNG with PIL alone (no plotting library is a dependency): linear or
log axes, intervals as bars, dashed reference lines; several charts stacked in one PNG.
Used for the neural stage's curves and the benchmarks' figures."""

from __future__ import annotations

import io
import math

from PIL import Image, ImageDraw, ImageFont

BLUE, RED, GREEN, GREY, ORANGE, PURPLE = (
    (31, 119, 180),
    (214, 39, 40),
    (44, 160, 44),
    (127, 127, 127),
    (255, 127, 14),
    (148, 103, 189),
)


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


def _log_ticks(lo: float, hi: float) -> list[float]:
    """Ticks of a log axis spanning log10 values lo..hi, as log10 values: 1, 2 and 5 times the
    powers of ten inside it (only the powers when those are many; every whole multiple when
    fewer than three fall inside, so a line near the top still has a value beside it; linear
    ticks when fewer than two fall inside even then)."""

    def inside_of(multiples) -> list[float]:
        marks = [math.log10(m * 10.0**k) for k in range(math.floor(lo), math.ceil(hi) + 1) for m in multiples]
        return [t for t in marks if lo <= t <= hi]

    inside = inside_of((1, 2, 5))
    if len(inside) < 3:
        inside = inside_of(range(1, 10))
    if len(inside) > 8:
        inside = [t for t in inside if abs(t - round(t)) < 1e-9]
    if len(inside) < 2:
        inside = [math.log10(v) for v in _nice_ticks(10**lo, 10**hi) if v > 0]
    return inside


def _tick_text(value: float) -> str:
    return f"{value:,.0f}" if abs(value) >= 1000 else f"{value:.3g}"


def chart(
    series: list[tuple[str, tuple, list]],
    title: str,
    xlabel: str,
    log_y: bool = False,
    log_x: bool = False,
    width: int = 640,
    height: int = 400,
) -> Image.Image:
    """A line chart: ``series`` is [(label, colour, [(x, y) or (x, y, lo, hi)])]; a 4-tuple
    point draws its interval as a vertical bar; a label starting with '--' draws a dashed
    line. Log axes drop points <= 0."""
    img = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(img)
    font = ImageFont.load_default()
    legend_width = 190 if any(label for label, _, _ in series) else 0
    left, right, top, bottom = 70, 20 + legend_width, 30, 45
    x0, x1, y0, y1 = left, width - right, top, height - bottom
    draw.rectangle([x0, y0, x1, y1], outline="black")
    draw.text((x0, 8), title, fill="black", font=font)
    draw.text(((x0 + x1) // 2 - 3 * len(xlabel), height - 18), xlabel, fill="black", font=font)

    def keep(p):
        return (not log_y or min(p[1:]) > 0) and (not log_x or p[0] > 0)

    points = [(label, colour, [p for p in pts if p[1] is not None and keep(p)]) for label, colour, pts in series]
    ys = [v for _, _, pts in points for p in pts for v in p[1:]]
    xs = [p[0] for _, _, pts in points for p in pts]
    if not ys:
        draw.text((x0 + 10, y0 + 10), "no finished epoch yet", fill="black", font=font)
        return img
    fy = math.log10 if log_y else float
    fx = math.log10 if log_x else float
    x_lo, x_hi = fx(min(xs)), fx(max(xs))
    if x_hi - x_lo < 1e-9:
        x_lo, x_hi = x_lo - 1, x_hi + 1
    y_lo, y_hi = fy(min(ys)), fy(max(ys))
    pad = 0.05 * (y_hi - y_lo) if y_hi > y_lo else (0.05 if log_y else 0.5)
    y_lo, y_hi = y_lo - pad, y_hi + pad

    def xy(x, y):
        return (x0 + (fx(x) - x_lo) / (x_hi - x_lo) * (x1 - x0), y1 - (fy(y) - y_lo) / (y_hi - y_lo) * (y1 - y0))

    for t in _log_ticks(y_lo, y_hi) if log_y else _nice_ticks(y_lo, y_hi):
        value = 10**t if log_y else t
        _, y = xy(xs[0], value)
        draw.line([x0 - 4, y, x0, y], fill="black")
        draw.text((5, y - 6), _tick_text(value), fill="black", font=font)
    for t in _log_ticks(x_lo, x_hi) if log_x else _nice_ticks(x_lo, x_hi):
        value = 10**t if log_x else t
        if log_x or float(value).is_integer():
            x, _ = xy(value, 10**y_lo if log_y else y_lo)
            draw.line([x, y1, x, y1 + 4], fill="black")
            text = _tick_text(value)
            half = draw.textlength(text, font=font) / 2  # centred under its tick, kept inside the image
            draw.text((min(max(x - half, 0), width - 2 * half - 2), y1 + 6), text, fill="black", font=font)
    for i, (label, colour, pts) in enumerate(points):
        dashed = label.startswith("--")
        coords = [xy(p[0], p[1]) for p in pts]
        for a, b in zip(coords, coords[1:]):
            if dashed:
                steps = max(1, int(math.dist(a, b) / 6))
                for k in range(0, steps, 2):
                    f0, f1 = k / steps, min(1.0, (k + 1) / steps)
                    draw.line(
                        [
                            (a[0] + (b[0] - a[0]) * f0, a[1] + (b[1] - a[1]) * f0),
                            (a[0] + (b[0] - a[0]) * f1, a[1] + (b[1] - a[1]) * f1),
                        ],
                        fill=colour,
                        width=2,
                    )
            else:
                draw.line([a, b], fill=colour, width=2)
        for p, (x, y) in zip(pts, coords):
            if len(p) == 4:
                _, lo = xy(p[0], p[2])
                _, hi = xy(p[0], p[3])
                draw.line([x, lo, x, hi], fill=colour, width=1)
                draw.line([x - 3, lo, x + 3, lo], fill=colour)
                draw.line([x - 3, hi, x + 3, hi], fill=colour)
            if not dashed:
                draw.ellipse([x - 3, y - 3, x + 3, y + 3], fill=colour)
        ly = y0 + 12 + 14 * i  # the legend beside the plot, never over its lines
        draw.line([x1 + 10, ly, x1 + 30, ly], fill=colour, width=2)
        draw.text((x1 + 35, ly - 6), label.lstrip("-"), fill="black", font=font)
    return img


def png(*images: Image.Image) -> bytes:
    """The images stacked vertically, as PNG bytes."""
    width = max(i.width for i in images)
    out_img = Image.new("RGB", (width, sum(i.height for i in images)), "white")
    y = 0
    for image in images:
        out_img.paste(image, (0, y))
        y += image.height
    out = io.BytesIO()
    out_img.save(out, format="PNG")
    return out.getvalue()
