"""The hand-written docs stay short enough to read (scripts/doc_words.py says which pages are
hand-written and how words are counted), carry no history, and state no machine's Python patch
version."""

import platform
import re
from pathlib import Path

from support.scripts import script_module

REPO = Path(__file__).resolve().parents[1]


def test_the_counting_rule_counts_what_it_says(tmp_path):
    script = script_module("doc_words")
    (tmp_path / "docs" / "results" / "x").mkdir(parents=True)
    (tmp_path / "README.md").write_text("one two three\n")
    (tmp_path / "docs" / "page.md").write_text("four  five\nsix\n")
    (tmp_path / "docs" / "results" / "bad-inputs.md").write_text("generated " * 5000)
    (tmp_path / "docs" / "results" / "x" / "README.md").write_text("generated " * 5000)
    (tmp_path / "docs" / "cli.md").write_text(
        "# Reference\n\nWritten by `x --write`; do not edit\nby hand.\n" + "w " * 5000
    )
    assert script.counts(tmp_path) == {"README.md": 3, "docs/page.md": 3}
    assert script.ISSUE_REFERENCE.search("as Issue 22 asked") and script.ISSUE_REFERENCE.search("issue_31")
    assert not script.ISSUE_REFERENCE.search("an issue with 3 parts")
    assert [m.group(1) for m in script.PYTHON_PATCH.finditer("Python here is 3.11.7, older than")] == ["3.11.7"]
    assert not script.PYTHON_PATCH.search("Python >= 3.10. The fixes landed in 3.11.13")


def test_the_hand_written_docs_are_within_their_word_limits():
    script = script_module("doc_words")
    per_page = script.counts()
    print(script.report(per_page))
    assert "README.md" in per_page and "docs/publish.md" in per_page
    too_long = {name: n for name, n in per_page.items() if n > script.PAGE_LIMIT}
    assert not too_long, f"pages over {script.PAGE_LIMIT} words: {too_long}"
    total = sum(per_page.values())
    assert total <= script.TOTAL_LIMIT, f"{total} words of hand-written docs, over {script.TOTAL_LIMIT}"


def test_no_page_or_test_name_refers_to_an_issue_number():
    script = script_module("doc_words")
    found = []
    for page in script.hand_written_pages():
        for n, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1):
            found += [f"{page.relative_to(REPO)}:{n}: {m.group()}" for m in script.ISSUE_REFERENCE.finditer(line)]
    for test in sorted((REPO / "tests").rglob("test_*.py")):
        names = [test.name] + re.findall(r"^\s*(?:async )?def (test\w*)", test.read_text(encoding="utf-8"), re.M)
        found += [f"{test.relative_to(REPO)}: {name}" for name in names if script.ISSUE_REFERENCE.search(name)]
    assert not found, "history belongs in CHANGELOG.md:\n" + "\n".join(found)


def test_no_page_states_which_python_patch_version_runs():
    """Which Python a machine runs belongs in a results page's head (docs/results/, written on that
    machine), never in a hand-written page: it is stale on the next machine (a fresh Debian 12 has
    its own, and so does every set-up a reader makes)."""
    script = script_module("doc_words")
    stated = []
    for page in script.hand_written_pages():
        text = page.read_text(encoding="utf-8")
        stated += [f"{page.relative_to(REPO)}: {m.group()!r}" for m in script.PYTHON_PATCH.finditer(text)]
    assert not stated, f"pages that state a Python patch version (this machine has {platform.python_version()}):\n" + (
        "\n".join(stated)
    )
