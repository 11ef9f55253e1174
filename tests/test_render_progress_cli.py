"""`shaderball render` shows its passes on stderr (done of total, spp, ETA) and, with --json,
keeps stdout to the one JSON document."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from support import VARIANT

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_render_shows_its_passes_on_stderr_and_json_keeps_stdout_to_one_document(tmp_path):
    out = tmp_path / "ball.exr"
    args = ["render", "--out", str(out), "--resolution", "16", "--spp", "7", "--variant", VARIANT, "--json"]
    done = subprocess.run(
        [sys.executable, "-c", "import cli; cli.main()", *args], cwd=REPO, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    doc = json.loads(done.stdout)  # the whole of stdout: one document, no progress in it
    assert doc["ok"] is True and doc["out"] == str(out)
    assert "pass 0/3 (0/7 spp)" in done.stderr and "ETA --:--" in done.stderr, done.stderr
    assert "pass 3/3 (7/7 spp)" in done.stderr and "ETA 0:00" in done.stderr, done.stderr
