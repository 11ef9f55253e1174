"""Sample outputs in the docs show the version the tool prints now.

Every `shaderball X.Y.Z` inside a fenced code block of README.md or a hand-written page of
docs/ (what a command printed) is `pipeline.__version__`; prose that dates a change ("since
shaderball 0.2.0") is history and is not a sample. Pages under docs/results/ are left out:
each names the command and date that wrote it, and keeps what that version printed."""

from __future__ import annotations

import re
from pathlib import Path

import pipeline

REPO = Path(__file__).resolve().parent.parent
FENCE = re.compile(r"^```[^\n]*\n(.*?)^```", re.S | re.M)
VERSION = re.compile(r"\bshaderball (\d+\.\d+\.\d+)\b")


def sample_versions(text: str) -> list[str]:
    return [v for block in FENCE.findall(text) for v in VERSION.findall(block)]


def hand_written_pages() -> list[Path]:
    return [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]


def test_sample_versions_are_the_tools():
    found = {}
    for page in hand_written_pages():
        for version in sample_versions(page.read_text(encoding="utf-8")):
            found.setdefault(version, []).append(page.relative_to(REPO).as_posix())
    assert found, "no sample output names a version: this test no longer checks anything"
    stale = {v: pages for v, pages in found.items() if v != pipeline.__version__}
    assert not stale, f"sample outputs show another version than shaderball {pipeline.__version__}: {stale}"


def test_a_stale_sample_is_caught():
    page = "```\ndataset out/smoke: smoke v1; built with shaderball 0.1.0, mitsuba 3.9.1\n```\nsince shaderball 0.0.9\n"
    assert sample_versions(page) == ["0.1.0"]
