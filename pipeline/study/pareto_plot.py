"""pareto.png: every configuration's error on the ball against its build-level CPU time,
coloured by family, the front, the recipes and each family's knee marked."""

from __future__ import annotations

import io
import math

from PIL import Image, ImageDraw, ImageFont

from pipeline.study.configs import aa_name

FAMILY_COLOURS = {
    "ladder": (31, 119, 180),
    "aa": (120, 120, 120),
    "denoise": (214, 39, 140),  # apart from the ladder's blue: the two are drawn together
    "samplers": (255, 127, 14),
    "passes": (0, 128, 128),
    "depth": (44, 160, 44),
    "rr": (148, 103, 189),
    "sun": (140, 86, 75),
    "clamp": (227, 119, 194),
    "robust": (188, 189, 34),
    "adaptive": (23, 190, 207),
}


def pareto_png(summary: list[dict], cmps: dict, recs: dict, knees: dict, width: int = 900, height: int = 600) -> bytes:
    """Error ratio on the ball against build-level CPU ratio, both to the recipe, log-log:
    every configuration with its 95% intervals, coloured by family; the A/A band (the
    recipe against itself: what no difference looks like); the recipe, the pick and each
    family's point where it stops paying marked; a legend."""
    img = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(img)
    font = ImageFont.load_default()
    fam = {s["config"]: s["family"] for s in summary}
    pts = [(n, c) for n, c in cmps.items() if c.get("ball") and c.get("cpu") and c["ball"]["value"] > 0]
    recipe = recs.get("paper", {}).get("config")
    if not pts:
        draw.text((70, 40), "no comparisons", fill="black", font=font)
        return _png(img)
    plot = _ParetoPlot(draw, font, pts, width, height)
    plot.axes(cmps.get(aa_name(int(recipe.split("/")[1]))) if recipe else None)
    families = [f for f in FAMILY_COLOURS if any(fam.get(n) == f for n, _ in pts)]
    plot.points(pts, fam, families)
    pick = (recs.get("paper_fast") or {}).get("config")
    plot.labels(pts, {k["config"] for k in knees.values()}, pick)
    plot.legend(families, recipe, pick, cmps)
    return _png(img)


class _ParetoPlot:
    """The drawing of :func:`pareto_png`: its frame, log-log axes fitted to the points'
    intervals, and what is drawn on them, in order."""

    def __init__(self, draw, font, pts: list, width: int, height: int):
        self.draw, self.font, self.height = draw, font, height
        left, right, top, bottom = 70, 250, 40, 50
        self.x0, self.x1, self.y0, self.y1 = left, width - right, top, height - bottom
        xs = [math.log10(v) for _, c in pts for v in (c["cpu"]["lo"], c["cpu"]["hi"]) if v > 0] + [0.0]
        ys = [math.log10(v) for _, c in pts for v in (c["ball"]["lo"], c["ball"]["hi"]) if v > 0] + [0.0]
        self.lx0, self.lx1 = math.floor(min(xs) * 4) / 4 - 0.05, math.ceil(max(xs) * 4) / 4 + 0.05
        self.ly0, self.ly1 = math.floor(min(ys) * 4) / 4 - 0.05, math.ceil(max(ys) * 4) / 4 + 0.05

    def xy(self, cpu, err):
        cpu, err = max(cpu, 10**self.lx0), max(err, 10**self.ly0)
        return (
            self.x0 + (math.log10(cpu) - self.lx0) / (self.lx1 - self.lx0) * (self.x1 - self.x0),
            self.y1 - (math.log10(err) - self.ly0) / (self.ly1 - self.ly0) * (self.y1 - self.y0),
        )

    def axes(self, aa: dict | None) -> None:
        """The A/A band, the frame, the ticks, the recipe's lines (1, 1) and the titles."""
        draw, font, xy = self.draw, self.font, self.xy
        x0, x1, y0, y1 = self.x0, self.x1, self.y0, self.y1
        if aa and aa.get("ball"):
            _, ya = xy(10**self.lx0, aa["ball"]["hi"])
            _, yb = xy(10**self.lx0, aa["ball"]["lo"])
            draw.rectangle([x0, ya, x1, yb], fill=(232, 232, 232))
        draw.rectangle([x0, y0, x1, y1], outline="black")
        for tick in (0.1, 0.2, 0.3, 0.5, 1, 2, 3, 5, 10, 20, 50, 100):
            lt = math.log10(tick)
            if self.lx0 <= lt <= self.lx1:
                x, _ = xy(tick, 10**self.ly0)
                draw.line([x, y1, x, y1 + 4], fill="black")
                draw.text((x - 8, y1 + 6), f"{tick:g}", fill="black", font=font)
            if self.ly0 <= lt <= self.ly1:
                _, y = xy(10**self.lx0, tick)
                draw.line([x0 - 4, y, x0, y], fill="black")
                draw.text((x0 - 30, y - 6), f"{tick:g}", fill="black", font=font)
        rx, ry = xy(1.0, 1.0)
        draw.line([x0, ry, x1, ry], fill=(200, 200, 200))
        draw.line([rx, y0, rx, y1], fill=(200, 200, 200))
        draw.text(
            (x0, 8),
            "relMSE on the ball / the recipe's (mean over samples and seeds) vs CPU per render / the recipe's",
            fill="black",
            font=font,
        )
        draw.text(
            (x0, 22), "(build-level CPU time; bars: 95% bootstrap intervals; grey band: A/A)", fill="black", font=font
        )
        draw.text(
            ((x0 + x1) // 2 - 100, self.height - 20),
            "CPU ratio to the recipe, build level (log)",
            fill="black",
            font=font,
        )

    def points(self, pts: list, fam: dict, families: list[str]) -> None:
        """Each family's points, with their intervals, joined by a line in CPU order."""
        draw, xy = self.draw, self.xy
        for f in families:
            colour = FAMILY_COLOURS[f]
            mine = sorted(((n, c) for n, c in pts if fam.get(n) == f), key=lambda nc: nc[1]["cpu"]["value"])
            if len(mine) > 1 and f != "aa":
                draw.line([xy(c["cpu"]["value"], c["ball"]["value"]) for _, c in mine], fill=colour, width=1)
            for _n, c in mine:
                x, y = xy(c["cpu"]["value"], c["ball"]["value"])
                xa, _ = xy(c["cpu"]["lo"], 1.0)
                xb, _ = xy(c["cpu"]["hi"], 1.0)
                _, ya = xy(1.0, c["ball"]["lo"])
                _, yb = xy(1.0, c["ball"]["hi"])
                draw.line([x, ya, x, yb], fill=colour, width=1)
                draw.line([xa, y, xb, y], fill=colour, width=1)
                draw.ellipse([x - 3, y - 3, x + 3, y + 3], fill=colour)

    def labels(self, pts: list, knee_names: set, pick: str | None) -> None:
        """The points' names (all of them when few; else the pick's and the knees'), and a
        ring around each knee. A label that would overprint one already drawn is left out
        (report.md lists every point); the pick and the knees are labelled first."""
        draw, xy = self.draw, self.xy
        label_all = len(pts) <= 25
        placed: list[tuple[float, float, float, float]] = []
        for n, c in sorted(pts, key=lambda nc: (nc[0] != pick, nc[0] not in knee_names)):
            if label_all or n in knee_names or n == pick:
                x, y = xy(c["cpu"]["value"], c["ball"]["value"])
                box = draw.textbbox((x + 5, y - 12), n, font=self.font)
                if not any(box[0] < b[2] and b[0] < box[2] and box[1] < b[3] and b[1] < box[3] for b in placed):
                    placed.append(box)
                    draw.text((x + 5, y - 12), n, fill=(60, 60, 60), font=self.font)
        for n, c in pts:
            if n in knee_names:
                x, y = xy(c["cpu"]["value"], c["ball"]["value"])
                draw.ellipse([x - 7, y - 7, x + 7, y + 7], outline="black", width=1)

    def legend(self, families: list[str], recipe: str | None, pick: str | None, cmps: dict) -> None:
        """The recipe's and the pick's marks, and the legend right of the plot."""
        draw = self.draw
        rx, ry = self.xy(1.0, 1.0)
        draw.rectangle([rx - 5, ry - 5, rx + 5, ry + 5], outline=(214, 39, 40), width=2)
        legend = [
            (f"family: {f}" if f != "aa" else "A/A: the recipe, other seeds", FAMILY_COLOURS[f]) for f in families
        ]
        legend.append((f"recipe: {recipe}", (214, 39, 40)))
        if pick and pick in cmps:
            x, y = self.xy(cmps[pick]["cpu"]["value"], cmps[pick]["ball"]["value"])
            draw.rectangle([x - 6, y - 6, x + 6, y + 6], outline=(0, 150, 0), width=2)
            legend.append((f"paper-fast pick: {pick}", (0, 150, 0)))
        legend.append(("ring: where a family stops paying", (0, 0, 0)))
        legend.append(("grey band: A/A 95% interval", (200, 200, 200)))
        for i, (label, colour) in enumerate(legend):
            y = self.y0 + 6 + 14 * i
            draw.line([self.x1 + 10, y + 6, self.x1 + 28, y + 6], fill=colour, width=3)
            draw.text((self.x1 + 32, y), label[:36], fill="black", font=self.font)


def _png(img) -> bytes:
    out = io.BytesIO()
    img.save(out, format="PNG")
    return out.getvalue()
