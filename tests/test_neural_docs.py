"""docs/neural.md's CPU-scale reproduction quotes the reports its commands wrote: every table
row of that section is a row of a file in docs/results/neural-mini/ (copied by
scripts/neural_repro_docs.sh, never retyped), and every picture it shows is shipped."""

import glob
import os
import re

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOC = os.path.join(REPO, "docs", "neural.md")
SHIPPED = os.path.join(REPO, "docs", "results", "neural-mini")
SECTION = "## A CPU-scale reproduction"


def _section() -> str:
    text = open(DOC, encoding="utf-8").read()
    assert SECTION in text
    body = text.split(SECTION, 1)[1]
    return body.split("\n## ", 1)[0]


def _shipped_lines() -> set[str]:
    lines = set()
    for path in glob.glob(os.path.join(SHIPPED, "**", "*"), recursive=True):
        if path.endswith((".md", ".log", ".txt", ".csv")):
            lines.update(line.rstrip() for line in open(path, encoding="utf-8"))
    return lines


def test_every_quoted_table_row_is_in_a_shipped_report():
    shipped = _shipped_lines()
    rows = [line.rstrip() for line in _section().splitlines() if line.startswith("| ") and re.search(r"\d", line)]
    assert len(rows) >= 10
    missing = [row for row in rows if row not in shipped]
    assert not missing, "rows not in docs/results/neural-mini/ (scripts/neural_repro_docs.sh):\n" + "\n".join(missing)


def test_every_picture_and_script_it_names_exists():
    section = _section()
    pictures = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", section)
    assert len(pictures) >= 3
    for picture in pictures:
        assert os.path.isfile(os.path.join(REPO, "docs", picture)), picture
    for script in set(re.findall(r"scripts/[\w.]+\.(?:sh|py)", section)):
        path = os.path.join(REPO, script)
        assert os.path.isfile(path) and os.access(path, os.X_OK), script


def test_the_equal_time_description_is_the_codes():
    """docs/neural.md says how `evaluate` measures equal time with the constants the code uses:
    how many CPU times it takes the least of, and the two spp it probes path tracing at."""
    from pipeline.neural.equal_time import EQUAL_TIME_PROBE_SPP, EQUAL_TIME_REPEATS

    text = " ".join(open(DOC, encoding="utf-8").read().split())  # prose wraps: single spaces
    said = re.search(
        r"the least of (\d+) CPU times of the network .*? path tracing at (\d+) spp and at (\d+) spp", text
    )
    assert said, "docs/neural.md no longer describes how equal time is measured"
    repeats, lo, hi = (int(g) for g in said.groups())
    assert repeats == EQUAL_TIME_REPEATS
    assert (lo, hi) == tuple(EQUAL_TIME_PROBE_SPP)
    assert "median of" not in text
