"""Line charts as PNG with PIL alone (no plotting library is a dependency): linear or
log axes, intervals as bars, dashed reference lines; several charts stacked in one PNG.
Used for the neural stage's curves and the benchmarks' figures."""

from __future__ import annotations

import io
import math
from collections.abc import Callable
from dataclasses import dataclass

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


@dataclass(frozen=True)
class _Plot:
    """The plot's box in pixels (``left`` < ``right``, ``top`` < ``bottom``) and the ranges its
    axes show, in axis units: the value on a linear axis, its log10 on a log axis (``to_x`` /
    ``to_y`` map a value to its axis unit)."""

    left: int
    right: int
    top: int
    bottom: int
    to_x: Callable[[float], float]
    to_y: Callable[[float], float]
    x_lo: float
    x_hi: float
    y_lo: float
    y_hi: float

    def pixel(self, x, y) -> tuple[float, float]:
        """The pixel of the point (x, y), given as values."""
        return (
            self.left + (self.to_x(x) - self.x_lo) / (self.x_hi - self.x_lo) * (self.right - self.left),
            self.bottom - (self.to_y(y) - self.y_lo) / (self.y_hi - self.y_lo) * (self.bottom - self.top),
        )


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
    box = (left, width - right, top, height - bottom)
    x0, x1, y0, y1 = box
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
    plot = _fit_plot(box, xs, ys, log_x, log_y)
    _draw_y_ticks(draw, font, plot, xs[0], log_y)
    _draw_x_ticks(draw, font, plot, width, log_x, log_y)
    for i, (label, colour, pts) in enumerate(points):
        _draw_series(draw, plot, colour, pts, dashed=label.startswith("--"))
        ly = y0 + 12 + 14 * i  # the legend beside the plot, never over its lines
        draw.line([x1 + 10, ly, x1 + 30, ly], fill=colour, width=2)
        draw.text((x1 + 35, ly - 6), label.lstrip("-"), fill="black", font=font)
    return img


def _fit_plot(box: tuple[int, int, int, int], xs: list, ys: list, log_x: bool, log_y: bool) -> _Plot:
    """The plot in ``box`` (left, right, top, bottom pixels) showing every x in ``xs`` and y in
    ``ys``: the y range padded by 5% so no line runs along the frame, a single x widened."""
    fy = math.log10 if log_y else float
    fx = math.log10 if log_x else float
    x_lo, x_hi = fx(min(xs)), fx(max(xs))
    if x_hi - x_lo < 1e-9:
        x_lo, x_hi = x_lo - 1, x_hi + 1
    y_lo, y_hi = fy(min(ys)), fy(max(ys))
    pad = 0.05 * (y_hi - y_lo) if y_hi > y_lo else (0.05 if log_y else 0.5)
    return _Plot(*box, fx, fy, x_lo, x_hi, y_lo - pad, y_hi + pad)


def _draw_y_ticks(draw: ImageDraw.ImageDraw, font, plot: _Plot, any_x: float, log_y: bool) -> None:
    """Ticks and values on the y axis (``any_x``: a value inside the x range, to place them)."""
    for t in _log_ticks(plot.y_lo, plot.y_hi) if log_y else _nice_ticks(plot.y_lo, plot.y_hi):
        value = 10**t if log_y else t
        _, y = plot.pixel(any_x, value)
        draw.line([plot.left - 4, y, plot.left, y], fill="black")
        draw.text((5, y - 6), _tick_text(value), fill="black", font=font)


def _draw_x_ticks(draw: ImageDraw.ImageDraw, font, plot: _Plot, width: int, log_x: bool, log_y: bool) -> None:
    """Ticks and values under the x axis; a linear axis ticks whole numbers only (epochs)."""
    for t in _log_ticks(plot.x_lo, plot.x_hi) if log_x else _nice_ticks(plot.x_lo, plot.x_hi):
        value = 10**t if log_x else t
        if log_x or float(value).is_integer():
            x, _ = plot.pixel(value, 10**plot.y_lo if log_y else plot.y_lo)
            draw.line([x, plot.bottom, x, plot.bottom + 4], fill="black")
            text = _tick_text(value)
            half = draw.textlength(text, font=font) / 2  # centred under its tick, kept inside the image
            draw.text((min(max(x - half, 0), width - 2 * half - 2), plot.bottom + 6), text, fill="black", font=font)


def _draw_series(draw: ImageDraw.ImageDraw, plot: _Plot, colour: tuple, pts: list, dashed: bool) -> None:
    """One series: its line (solid, or dashed for a reference), its intervals as bars, and a
    dot on each point of a solid line."""
    coords = [plot.pixel(p[0], p[1]) for p in pts]
    for a, b in zip(coords, coords[1:]):
        if dashed:
            _draw_dashes(draw, a, b, colour)
        else:
            draw.line([a, b], fill=colour, width=2)
    for p, (x, y) in zip(pts, coords):
        if len(p) == 4:
            _, lo = plot.pixel(p[0], p[2])
            _, hi = plot.pixel(p[0], p[3])
            draw.line([x, lo, x, hi], fill=colour, width=1)
            draw.line([x - 3, lo, x + 3, lo], fill=colour)
            draw.line([x - 3, hi, x + 3, hi], fill=colour)
        if not dashed:
            draw.ellipse([x - 3, y - 3, x + 3, y + 3], fill=colour)


def _draw_dashes(draw: ImageDraw.ImageDraw, a: tuple[float, float], b: tuple[float, float], colour: tuple) -> None:
    """The segment from pixel ``a`` to pixel ``b`` as dashes of about 6 pixels."""
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
