"""Count the words of the hand-written docs: README.md and docs/*.md.

    .venv/bin/python scripts/doc_words.py          # a line per page, largest first, then the total

Which pages are hand-written, by one rule: a page is generated when it lives under
docs/results/ (every results page is written there by the command named in its first
lines) or when its first lines say "do not edit by hand" (docs/cli.md, written from the
click commands); every other page of README.md and docs/*.md is hand-written. Pages in other
folders under docs/ (shipped reports, pictures) are not pages of the docs' text and are
not counted either: only README.md and the files directly in docs/ are.

A word is what `wc -w` counts: a run of characters between white space.
tests/test_doc_words.py holds the counts to the limits below.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: The most words the hand-written docs may hold, all together and on one page.
TOTAL_LIMIT = 25_000
PAGE_LIMIT = 3_000

#: "issue 12", "Issue 3": history, which belongs in the CHANGELOG, not in a page or a test's name.
ISSUE_REFERENCE = re.compile(r"\bissue[ _-]?#?\d+", re.IGNORECASE)

#: A Python patch version a page gives, "Python 3.11.7" or "Python here is 3.11.7" (within a sentence).
PYTHON_PATCH = re.compile(r"\bPython\b[^.\n]{0,40}?\b(\d+\.\d+\.\d+)")


#: What the head of a generated page outside docs/results/ says.
GENERATED_MARK = "do not edit by hand"


def _generated(page: Path) -> bool:
    with page.open(encoding="utf-8") as fh:
        head = " ".join(line for _, line in zip(range(5), fh))
    return GENERATED_MARK in " ".join(head.split())


def hand_written_pages(repo: Path = REPO) -> list[Path]:
    """README.md and docs/*.md but generated ones; nothing under docs/results/ or other sub-folders."""
    pages = [repo / "README.md"] + sorted((repo / "docs").glob("*.md"))
    return [page for page in pages if page.is_file() and not _generated(page)]


def words(text: str) -> int:
    return len(text.split())


def counts(repo: Path = REPO) -> dict[str, int]:
    """Words per hand-written page, keyed by its path relative to the repository."""
    return {str(page.relative_to(repo)): words(page.read_text(encoding="utf-8")) for page in hand_written_pages(repo)}


def report(per_page: dict[str, int]) -> str:
    lines = [f"{n:7,d}  {name}" for name, n in sorted(per_page.items(), key=lambda item: -item[1])]
    lines.append(f"{sum(per_page.values()):7,d}  in all ({len(per_page)} hand-written pages)")
    return "\n".join(lines)


if __name__ == "__main__":
    print(report(counts()))
    sys.exit(0)
