"""Why a build's render calls run slower than bare renders on a CPU: the threads beside them.

    .venv/bin/python scripts/writer_priority.py --repeats 5 --out docs/results/writer-priority

Runs `shaderball bench SPEC --renders N --resolution 400 --spp 1 --workers 0` (an in-process build,
then bare renders of the same scenes) in fresh processes, alternating two arms, `--repeats`
times each:

- **as built**: the build's helper threads (the shard's EXR writer, the next material's maps)
  at the build's own priority, as `shaderball build` runs them;
- **helpers niced**: the same threads at nice 19 (Linux keeps a nice value per thread), so the
  render's threads win every core while they want it.

If the render calls are slow because the helpers take cores from them, niced helpers bring the
render calls back to the bare renders' speed; whether the build as a whole gains is the other
question the page answers. Each run's figures come from the bench's own `--json-out`. Writes
OUT/README.md (headed by this command, the machine and the date) and OUT/runs.json: each run,
the medians, and the paired differences (run k of one arm against run k of the other) with a
95% Student-t interval.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from scipy import stats as scipy_stats  # noqa: E402

from scripts.results_page import head  # noqa: E402

#: Runs the CLI with the build's helper threads (pipeline.run.shard's ThreadPoolExecutors) at
#: the nice value argv[1]; the rest of argv is the CLI's.
CHILD = """
import concurrent.futures, os, runpy, sys, threading
import pipeline.run.shard as shard
nice = int(sys.argv[1])
class Pool(concurrent.futures.ThreadPoolExecutor):
    def __init__(self, *args, **kwargs):
        def lower():
            if nice:
                os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), nice)
        super().__init__(*args, initializer=lower, **kwargs)
shard.ThreadPoolExecutor = Pool
sys.argv = ["cli", *sys.argv[2:]]
runpy.run_module("cli", run_name="__main__")
"""
ARMS = {"as built": 0, "helpers niced": 19}

#: (label, how a run's bench JSON gives it)
FIGURES = [
    ("render calls inside the build / bare renders", lambda d: d["render_call_ratio"]),
    ("build wall / bare renders' wall", lambda d: d["ratio"]),
    ("build CPU / bare renders' CPU", lambda d: d["cpu_ratio"]),
    ("build, ms per render", lambda d: 1e3 * d["build_s"] / d["samples"]),
    ("writer waits, ms per render", lambda d: 1e3 * d["in_build_phases"]["writer waits"] / d["samples"]),
    (
        "main thread outside its render calls, CPU ms per render",
        lambda d: 1e3 * (d["in_build_main_cpu_s"] - d["in_build_phases_cpu"]["render calls"]) / d["samples"],
    ),
    ("writer thread CPU, ms per render", lambda d: 1e3 * d["in_build_phases_cpu"]["writer thread"] / d["samples"]),
]


def run_once(nice: int, bench_args: list[str], json_path: str) -> dict:
    argv = [sys.executable, "-c", CHILD, str(nice), "bench", *bench_args, "--json-out", json_path]
    env = dict(os.environ, PYTHONPATH=str(REPO))
    done = subprocess.run(argv, cwd=REPO, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"bench failed (nice {nice}): {done.stderr[-2000:]}")
    return json.loads(Path(json_path).read_text())


def interval(diffs: list[float]) -> tuple[float, float, float]:
    """Mean of ``diffs`` and its 95% Student-t interval."""
    mean = statistics.fmean(diffs)
    if len(diffs) < 2:
        return mean, float("nan"), float("nan")
    half = scipy_stats.t.ppf(0.975, len(diffs) - 1) * statistics.stdev(diffs) / len(diffs) ** 0.5
    return mean, mean - half, mean + half


def page(command: str, bench_args: list[str], runs: dict[str, list[dict]], load: list[str]) -> str:
    arms = list(ARMS)
    lines = [
        head("The build's render calls against bare renders: the helper threads' share of the CPU", command).rstrip(
            "\n"
        ),
        "",
        f"Each run: `shaderball bench {' '.join(bench_args)}` in a fresh process; the arms alternate "
        f"({len(runs[arms[0]])} runs each). **as built**: the build's helper threads (the shard's EXR writer, the "
        "next material's maps) at the build's own priority; **helpers niced**: the same threads at nice 19. "
        f"Load average before each run: {', '.join(load)}.",
        "",
        "## Medians",
        "",
        "| figure | " + " | ".join(arms) + " | niced - as built: mean, 95% interval |",
        "|---|---|---|---|",
    ]
    for label, get in FIGURES:
        values = {arm: [get(d) for d in runs[arm]] for arm in arms}
        diffs = [b - a for a, b in zip(values[arms[0]], values[arms[1]])]
        mean, low, high = interval(diffs)
        cells = " | ".join(f"{statistics.median(values[arm]):.3f}" for arm in arms)
        lines.append(f"| {label} | {cells} | {mean:+.3f} [{low:+.3f}, {high:+.3f}] |")
    lines += ["", "## Every run", "", "| arm | run | " + " | ".join(label for label, _ in FIGURES) + " |"]
    lines.append("|---|---|" + "---|" * len(FIGURES))
    for arm in arms:
        for k, d in enumerate(runs[arm], 1):
            lines.append(f"| {arm} | {k} | " + " | ".join(f"{get(d):.3f}" for _, get in FIGURES) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spec", default="manifests/paper.toml")
    parser.add_argument("--limit", type=int, default=100, help="renders per run (the paper's shape: 100 a shard)")
    parser.add_argument("--resolution", type=int, default=400)
    parser.add_argument("--spp", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", required=True, help="folder for README.md and runs.json")
    args = parser.parse_args(argv)
    if args.repeats < 2:
        parser.error(f"--repeats: {args.repeats}; 2 or more (a 95% interval needs two pairs)")
    if args.limit < 1:
        parser.error(f"--limit: {args.limit}; 1 or more renders")
    if os.path.exists(args.out) and not os.path.isdir(args.out):  # before the runs: minutes
        parser.error(f"--out: {args.out} exists and is not a folder")
    if not os.path.isfile(args.spec):
        parser.error(f"--spec: {args.spec} is not a file")
    bench_args = [args.spec, "--renders", str(args.limit), "--resolution", str(args.resolution)]
    bench_args += ["--spp", str(args.spp), "--workers", "0"]
    command = ".venv/bin/python scripts/writer_priority.py " + shlex.join(
        ["--spec", args.spec, "--limit", str(args.limit), "--resolution", str(args.resolution)]
        + ["--spp", str(args.spp), "--repeats", str(args.repeats), "--out", args.out]
    )
    runs: dict[str, list[dict]] = {arm: [] for arm in ARMS}
    load = []
    with tempfile.TemporaryDirectory() as scratch:
        for k in range(args.repeats):
            order = list(ARMS) if k % 2 == 0 else list(reversed(ARMS))
            for arm in order:
                load.append(f"{os.getloadavg()[0]:.2f}")
                print(f"run {k + 1}/{args.repeats}: {arm} ...", file=sys.stderr, flush=True)
                runs[arm].append(run_once(ARMS[arm], bench_args, os.path.join(scratch, "bench.json")))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    text = page(command, bench_args, runs, load)
    (out / "README.md").write_text(text)
    (out / "runs.json").write_text(json.dumps({"command": command, "arms": ARMS, "runs": runs}, indent=1) + "\n")
    print(text)


if __name__ == "__main__":
    main()
