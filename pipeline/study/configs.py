"""The configurations a study measures, each varied from the spec's own recipe.

A configuration is a name, a family, the render settings it changes and, for denoising
and the robust pass combinations, a post-process. The list is pure: a function of the
spec's recipe, the spp ladder and the families asked for.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from pipeline.render.limits import SAMPLERS

#: The spp ladder: powers of two and the paper's 150.
DEFAULT_LADDER = (1, 2, 4, 8, 16, 32, 64, 128, 150, 256, 512, 1024)
#: Families, in the order they are run and reported.
FAMILIES = ("ladder", "denoise", "samplers", "passes", "depth", "rr", "sun", "clamp", "robust", "adaptive")
#: Families whose estimate converges to the reference's image: the candidates for a faster
#: recipe of the same meaning. Depth cuts, clamps, robust combinations and denoisers are biased.
UNBIASED_FAMILIES = ("ladder", "samplers", "passes", "rr", "adaptive")
SAMPLER_SPP = (4, 16, 32, 48, 64, 96, 128, 150, 256)
#: A stratifying sampler's budget split into equal passes that it takes exactly (16 = 4^2
#: and 64 = 8^2 for all three: no rounding), each a power of two, so the render stays
#: byte-reproducible where one pass of 32, 48 or 128 would be rounded (multijitter: 35,
#: 51, 132): (passes, spp each).
PASS_SPLITS = ((2, 16), (3, 16), (4, 16), (2, 64))
PASS_SAMPLERS = ("stratified", "multijitter", "ldsampler")
DEPTHS = (1, 2, 3, 4, 6, 12, 16)
RR_DEPTHS = (1, 2, 3, 8)
CLAMPS = (1.0, 4.0, 16.0, 64.0)
#: Robust combinations: this many equal power-of-two passes of each size.
ROBUST_PASSES = 8
ROBUST_PASS_SPP = (4, 16, 32)
#: Targets of the adaptive renderer (sqrt of an estimated relMSE), capped at the largest
#: ladder rung up to 4x the recipe's spp.
ADAPTIVE_TARGETS = (0.05, 0.03, 0.02, 0.01)
#: Post-processes: OIDN with albedo+normal guides, OIDN on the colour alone, and the
#: robust combinations of equal passes (mean: the plain average, for comparison).
POSTS = ("oidn", "oidn-color", "mean", "trim", "mom")


@dataclass(frozen=True)
class Config:
    name: str
    family: str
    spp: int
    changes: dict = field(default_factory=dict)  # RenderSettings fields other than spp
    post: str | None = None  # one of POSTS
    passes: tuple[int, ...] = ()  # robust: the equal pass sizes
    #: Renders the same settings with other seeds (the A/A configuration: "aa").
    seed_tag: str = ""

    def settings_key(self) -> tuple:
        """Configurations with equal keys share one render (denoising reuses the ladder's)."""
        key = (self.spp, tuple(sorted(self.changes.items())), self.passes)
        return (*key, self.seed_tag) if self.seed_tag else key

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "family": self.family,
            "spp": self.spp,
            "changes": dict(self.changes),
            "post": self.post,
            "passes": list(self.passes),
            "seed_tag": self.seed_tag,
        }


def paper_name(spp: int) -> str:
    return f"independent/{spp}"


def aa_name(spp: int) -> str:
    """The A/A configuration: the recipe again, with other seeds (the noise floor)."""
    return f"A/A {paper_name(spp)}"


def study_configs(
    recipe_spp: int, recipe_sun: str, ladder: tuple[int, ...], families: tuple[str, ...], recipe_max_depth: int = 8
) -> list[Config]:
    """Every configuration of the study, the spec's recipe (independent/recipe_spp) included."""
    ladder = tuple(sorted(set(ladder) | {recipe_spp}))
    top = max(ladder)
    out: list[Config] = [Config(paper_name(n), "ladder", n) for n in ladder]
    out.append(Config(aa_name(recipe_spp), "aa", recipe_spp, seed_tag="aa"))
    if "denoise" in families:
        for post in ("oidn", "oidn-color"):
            out += [Config(f"{post}+independent/{n}", "denoise", n, post=post) for n in ladder if n <= 256]
    if "samplers" in families:
        for sampler in SAMPLERS[1:]:
            out += [Config(f"{sampler}/{n}", "samplers", n, {"sampler": sampler}) for n in SAMPLER_SPP if n <= top]
    if "passes" in families:
        out += [
            Config(f"{sampler}/{n}x{p}", "passes", n * p, {"sampler": sampler}, post="mean", passes=(p,) * n)
            for sampler in PASS_SAMPLERS
            for n, p in PASS_SPLITS
            if n * p <= top
        ]
    if "depth" in families:
        out += [
            Config(f"depth{d}/{recipe_spp}", "depth", recipe_spp, {"max_depth": d})
            for d in DEPTHS
            if d != recipe_max_depth
        ]
    if "rr" in families:
        out += [Config(f"rr{d}/{recipe_spp}", "rr", recipe_spp, {"rr_depth": d}) for d in RR_DEPTHS]
    if "sun" in families:
        other = "sunsky" if recipe_sun == "split" else "split"
        out += [Config(f"{other}/{n}", "sun", n, {"sun": other}) for n in sorted({16, 64, recipe_spp, 256}) if n <= top]
    if "clamp" in families:
        out += [Config(f"clamp{c:g}/{recipe_spp}", "clamp", recipe_spp, {"clamp": c}) for c in CLAMPS]
    if "robust" in families:
        for p in ROBUST_PASS_SPP:
            if p * ROBUST_PASSES <= top:
                out += [
                    Config(
                        f"{post}{ROBUST_PASSES}x{p}",
                        "robust",
                        p * ROBUST_PASSES,
                        post=post,
                        passes=(p,) * ROBUST_PASSES,
                    )
                    for post in ("mean", "trim", "mom")
                ]
    if "adaptive" in families:
        cap = max([n for n in ladder if n <= 4 * recipe_spp] or [top])
        out += [Config(f"adaptive{t:g}/{cap}", "adaptive", cap, {"target_error": t}) for t in ADAPTIVE_TARGETS]
    names = [c.name for c in out]
    assert len(names) == len(set(names)), "configuration names must be unique"
    return out
