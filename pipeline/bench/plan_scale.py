"""How a spec of millions of renders plans and starts building: a measurement, reported,
not a timed test.

    .venv/bin/python scripts/plan_scale.py [--materials 1000000] [--lights 10]

In fresh processes (so peak memory is the plan's, not this one's):

1. planning: parse the spec, :func:`pipeline.dataset.plan.plan_dataset`, its summary, one
   shard's samples; wall time and peak resident memory (``ru_maxrss``);
2. the plan digest a build writes into dataset.json (every shard planned and hashed,
   streamed): wall time and peak memory;
3. ``shaderball build SPEC --out TMP --workers 0``: seconds until its first progress line
   on stderr; the build is then stopped and TMP removed.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

_PLAN = """
import json, resource, sys, time
start = time.perf_counter()
from pipeline.dataset.plan import plan_dataset, plan_summary
from pipeline.dataset.spec_file import parse_spec
imported = time.perf_counter()
plans = plan_dataset(parse_spec(sys.argv[1]))
summary = plan_summary(plans)
first = plans[0].samples
planned = time.perf_counter()
out = {"plan_s": planned - imported, "renders": summary["renders"], "shards": summary["shards"],
       "first_shard_samples": len(first)}
if sys.argv[2] == "digest":
    from pipeline.run.out_folder import plan_digest
    t = time.perf_counter()
    out["digest"] = plan_digest(plans)[:12]
    out["digest_s"] = time.perf_counter() - t
out["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps(out))
"""


def spec_text(materials: int, lights: int, shard_size: int) -> str:
    return (
        f'[dataset]\nname = "scale"\nseed = 1\nmaterials = {materials}\nlights_per_material = {lights}\n'
        f"shard_size = {shard_size}\n\n[render]\nresolution = 32\nspp = 1\n"
    )


def measure_plan(spec: Path, digest: bool) -> dict:
    done = subprocess.run(
        [sys.executable, "-c", _PLAN, str(spec), "digest" if digest else "plan"],
        cwd=REPO,
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(done.stdout)


def first_progress(spec: Path, out: Path, timeout_s: float = 120.0) -> tuple[float, str]:
    """Seconds from starting ``shaderball build`` to its first progress line, and the line."""
    start = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", "cli", "build", str(spec), "--out", str(out), "--workers", "0"],
        cwd=REPO,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        deadline = start + timeout_s
        while time.perf_counter() < deadline:
            line = proc.stderr.readline()
            if not line:
                break
            if "renders" in line and "/" in line:
                return time.perf_counter() - start, line.strip()
        return float("nan"), "no progress line"
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def measure_plan_scale(materials: int = 1_000_000, lights: int = 10, shard_size: int = 20) -> dict:
    """Steps 1 to 3 on a spec of ``materials`` x ``lights`` renders in a temporary folder:
    ``{"materials", "lights", "plan": {...}, "digest": {...}, "first_progress_s", "first_progress_line"}``."""
    with tempfile.TemporaryDirectory(prefix="plan-scale-") as tmp:
        spec = Path(tmp) / "scale.toml"
        spec.write_text(spec_text(materials, lights, shard_size))
        plan = measure_plan(spec, digest=False)
        digest = measure_plan(spec, digest=True)
        seconds, line = first_progress(spec, Path(tmp) / "out")
        shutil.rmtree(Path(tmp) / "out", ignore_errors=True)
    return {
        "materials": materials,
        "lights": lights,
        "plan": plan,
        "digest": digest,
        "first_progress_s": seconds,
        "first_progress_line": line,
    }


def plan_scale_lines(result: dict) -> list[str]:
    """The measurement of :func:`measure_plan_scale` as lines for people."""
    plan, digest = result["plan"], result["digest"]
    return [
        f"spec: {result['materials']} materials x {result['lights']} lightings = {plan['renders']} renders in "
        f"{plan['shards']} shards",
        f"planning (plan_dataset + summary + one shard): {plan['plan_s']:.2f} s, peak RSS of the process "
        f"{plan['peak_rss_mib']:.0f} MiB (imports included)",
        f"plan digest (every shard planned and hashed, streamed): {digest['digest_s']:.1f} s, peak RSS "
        f"{digest['peak_rss_mib']:.0f} MiB",
        f"shaderball build: first progress line after {result['first_progress_s']:.1f} s: "
        f"{result['first_progress_line']}",
    ]
