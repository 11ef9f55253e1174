"""docs/accuracy.md and the specs' comments quote the study's reports, never retype them.

- Every block of docs/accuracy.md marked ``<!-- copied from REPORT -->`` ... ``<!-- end of
  copy -->`` appears verbatim in that shipped report (docs/results/REPORT).
- Every recipe claim (a line "CONFIG against RECIPE (..., 95% intervals): ...") in
  docs/accuracy.md and in manifests/*.toml is one of a shipped report's claim lines; a
  paper-fast spec ships only with its claim that it replaces the recipe (in the docs and
  its comments), and a withdrawn one's claim is quoted with the withdrawal.
- The 400x400 single-seed check (docs/results/accuracy-400px-8/report.md): the docs' count of the
  samples where multijitter/64 is worse than the paper recipe is that report's count.
"""

from __future__ import annotations

import glob
import os
import re

import tomllib

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOCS = os.path.join(REPO, "docs")
RESULTS = os.path.join(DOCS, "results")
ACCURACY = os.path.join(DOCS, "accuracy.md")
COPY = re.compile(r"<!-- copied from ([\w./-]+) -->\n(.*?)\n<!-- end of copy -->", re.S)
CLAIM = re.compile(r"(?:A/A )?\S+ against independent/\d+ \(\d+x\d+, \d+ samples x \d+ seeds, 95% intervals\): .*")


def _read(path):
    with open(path, encoding="utf-8") as fh:
        return fh.read()


def report_claims() -> set[str]:
    claims = set()
    for path in glob.glob(os.path.join(RESULTS, "accuracy-*", "report.md")):
        text = _read(path)
        if "### Claims" in text:
            section = text.split("### Claims", 1)[1]
            claims |= {line[2:] for line in section.splitlines() if line.startswith("- ")}
    return claims


def quoted_claims(text: str) -> list[str]:
    return [m.group(0).strip() for line in text.splitlines() for m in [CLAIM.search(line)] if m]


def test_copied_blocks_are_verbatim_copies_of_the_shipped_reports():
    doc = _read(ACCURACY)
    blocks = COPY.findall(doc)
    assert blocks, "docs/accuracy.md quotes no report"
    for name, body in blocks:
        assert body.strip() in _read(os.path.join(RESULTS, name)), f"block copied from {name} differs from it"


#: The recipe paper-fast.toml had (multijitter, 64 spp): withdrawn by the 128-px decision.
WITHDRAWN_RECIPE = "multijitter/64"


def test_recipe_claims_in_docs_and_specs_are_the_reports_own():
    claims = report_claims()
    assert claims
    for path in [ACCURACY, *glob.glob(os.path.join(REPO, "manifests", "*.toml"))]:
        for line in quoted_claims(_read(path)):
            assert line in claims, f"{os.path.relpath(path, REPO)}: claim not in a shipped report: {line}"


def test_paper_fast_is_decided_by_the_rule_as_the_docs_say():
    """A paper-fast spec ships only with a claim that it replaces the recipe; the withdrawn
    recipe's claim (does not replace) is quoted in the docs, with the withdrawal."""
    doc = _read(ACCURACY)
    path = os.path.join(REPO, "manifests", "paper-fast.toml")
    if os.path.exists(path):
        spec = tomllib.loads(_read(path))["render"]
        own = f"{spec['sampler']}/{spec['spp']} against independent/"
        for text in (doc, _read(path)):
            mine = [q for q in quoted_claims(text) if q.startswith(own)]
            assert mine and all(q.endswith(": replaces the recipe") for q in mine)
    else:
        mine = [q for q in quoted_claims(doc) if q.startswith(f"{WITHDRAWN_RECIPE} against independent/")]
        assert mine and all("does not replace the recipe" in q for q in mine)
        assert "paper-fast is withdrawn" in doc


def _class_table(text: str) -> dict[str, list[float]]:
    section = text.split("## Per material class", 1)[1]
    rows = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) > 1 and re.fullmatch(r"\d[\d.e+-]*", cells[1]):
            rows[cells[0]] = [float(c) for c in cells[1:]]
    return rows


def test_the_400px_count_is_the_reports():
    table = _class_table(_read(os.path.join(RESULTS, "accuracy-400px-8", "report.md")))
    fast, paper = table["multijitter/64"], table["independent/150"]
    worse = sum(f > p for f, p in zip(fast, paper))
    mean_fast, mean_paper = sum(fast) / len(fast), sum(paper) / len(paper)
    doc = " ".join(_read(ACCURACY).split())  # prose wraps: compare with single spaces
    assert f"worse on {worse} of {len(fast)}" in doc
    short = lambda x: f"{x:.1e}".replace("e-0", "e-")  # noqa: E731  5.9e-4, as the docs write it
    assert f"mean relMSE {short(mean_fast)} against {short(mean_paper)}" in doc
    for path in [ACCURACY, *glob.glob(os.path.join(REPO, "manifests", "*.toml"))]:
        assert "better or equal on 5 of 8" not in _read(path), path
