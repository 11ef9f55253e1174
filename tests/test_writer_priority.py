"""scripts/writer_priority.py: the experiment behind the build's render calls against bare renders
(docs/build.md) runs end to end on a tiny spec and writes its page; its interval is Student's t."""

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from scripts.writer_priority import ARMS, FIGURES, interval  # noqa: E402


def test_interval_is_the_student_t_95_percent_interval():
    mean, low, high = interval([1.0, 2.0, 3.0])  # sd 1, n 3: t(0.975, 2) = 4.3027
    assert mean == 2.0
    assert high - mean == pytest.approx(4.3027 / math.sqrt(3), rel=1e-4)
    assert mean - low == pytest.approx(high - mean)
    assert math.isnan(interval([1.0])[1])


def test_experiment_writes_its_page_and_runs(tmp_path):
    out = tmp_path / "wp"
    args = ["--spec", "manifests/smoke.toml", "--limit", "4", "--resolution", "16", "--repeats", "2", "--out", str(out)]
    done = subprocess.run(
        [sys.executable, "scripts/writer_priority.py", *args], cwd=REPO, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr[-2000:]
    doc = json.loads((out / "runs.json").read_text())
    assert doc["arms"] == ARMS and all(len(doc["runs"][arm]) == 2 for arm in ARMS)
    for arm in ARMS:
        for run in doc["runs"][arm]:
            assert run["samples"] == 4 and run["resolution"] == 16 and run["workers"] == "in-process (no dask)"
    page = (out / "README.md").read_text()
    assert page.startswith("# ") and "Written by `.venv/bin/python scripts/writer_priority.py --spec" in page
    for label, _ in FIGURES:
        assert sum(line.startswith(f"| {label} |") for line in page.splitlines()) == 1, label
    assert sum(line.startswith("| as built | ") for line in page.splitlines()) == 2


@pytest.mark.parametrize(
    ("args", "message"), [(["--repeats", "1"], "--repeats: 1; 2 or more"), (["--limit", "0"], "--limit: 0; 1 or more")]
)
def test_too_few_runs_or_renders_exit_2_and_write_nothing(tmp_path, args, message):
    out = tmp_path / "wp"
    done = subprocess.run(
        [sys.executable, "scripts/writer_priority.py", *args, "--out", str(out)],
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2 and message in done.stderr, done.stderr
    assert not out.exists()
