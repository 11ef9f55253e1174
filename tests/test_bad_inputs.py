"""Every bad input of docs/results/bad-inputs.md: non-zero exit, a message naming the input, nothing
written; and the table of that generated page is the one the script prints today."""

from pathlib import Path

from support.scripts import script_module

REPO = Path(__file__).resolve().parents[1]


def test_every_bad_input_is_refused_cleanly():
    script = script_module("bad_inputs")
    rows = script.run_all()
    assert len(rows) >= 30
    for row in rows:
        assert row["exit_code"] == 2, row
        assert not row["wrote"], row
        assert "UNCAUGHT" not in row["message"] and ("error" in row["message"].lower()), row
        if "--json" in row["argv"]:  # one JSON document on stdout
            assert row["json"]["ok"] is False and row["json"]["exit"] == 2 and row["json"]["error"], row
    page = script.PAGE.read_text()
    assert script.table(rows) in page, "docs/results/bad-inputs.md is stale: re-run scripts/bad_inputs.py --write"
    assert page.startswith("# Bad inputs run through the CLI\n\nWritten by `.venv/bin/python scripts/bad_inputs.py")
    readme = (REPO / "README.md").read_text()
    assert f"{len(rows)} bad inputs run through the CLI" in readme, "README.md's count is stale: --write it"
