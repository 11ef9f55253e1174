"""What another CPU changes, measured under emulated CPUs (docs/build.md).

Runs ``scripts/cross_cpu.py`` on a 4-render cut of the smoke spec: four real
builds, each in a fresh process with fresh kernel and geometry caches. What must hold on any
machine: the plan is the same under every emulation (plan format 2), and a render made for
another CPU differs from this one's far inside its own noise. Which files stay byte-identical
is the machine's business and is reported, not asserted.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from support.plans import REPO, SMOKE


@pytest.mark.slow
def test_builds_for_another_cpu_have_the_same_plan_and_renders_within_their_noise(tmp_path):
    spec = tmp_path / "smoke4.toml"
    spec.write_text(SMOKE.read_text().replace("materials = 8 ", "materials = 2 "))
    out = tmp_path / "cross"
    run = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "cross_cpu.py"), str(spec), "--out", str(out), "--json"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,  # ~25 s of CPU: fails with the command named before pytest's 900 s would
    )
    assert run.returncode == 0, run.stderr
    result = json.loads(run.stdout)
    assert result == json.loads((out / "report.json").read_text())
    report = (out / "report.md").read_text()
    assert report.startswith("# What another CPU changes")
    assert report.splitlines()[2] == f"Written by `{result['command']}` on {result['date']}."  # and the machine below
    assert result["date"].startswith("20") and result["date"].endswith(" UTC")
    builds = result["builds"]
    assert {"native", "numpy-avx2"} <= set(builds)
    for name, row in builds.items():
        assert row["plan_digest_equal"], name
        assert row["files"]["render"]["files"] == 4, name
        if row["renders_differing"]:
            # two independent renders differ by ~1.41 noise; a retargeted JIT's by far less
            assert row["rmse_over_noise"]["max"] < 0.2, (name, row)
    native = builds["native"]
    assert native["renders_differing"] == 0 and native["files"]["maps"]["identical"] == native["files"]["maps"]["files"]
