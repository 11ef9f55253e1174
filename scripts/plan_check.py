"""How close `shaderball plan` comes: plan each spec, build it, compare time and disk.

    .venv/bin/python scripts/plan_check.py manifests/smoke.toml manifests/mini.toml --out docs/results/plan

For each spec: `shaderball plan SPEC --workers 0` (its text, shown on the page, and its
JSON), then `shaderball build SPEC --workers 0` into a temporary folder (removed after),
timed as a whole command; then the folder's size as written. Writes OUT/README.md (headed by
this command, the machine and the date) and OUT/plan-check.json. Both sides run in this one
process's children on this machine, one after the other, so the load they see is similar;
the page gives the load average before each.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from scripts.results_page import head  # noqa: E402


def _shaderball(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cli", *args], cwd=REPO, capture_output=True, text=True, check=False)


def _checked(result: subprocess.CompletedProcess, what: str) -> subprocess.CompletedProcess:
    if result.returncode != 0:
        sys.exit(f"{what} exited {result.returncode}:\n{result.stderr}")
    return result


def _folder_bytes(folder: str) -> int:
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, files in os.walk(folder) for f in files)


def check(spec: str) -> dict:
    load = os.getloadavg()[0]
    text = _checked(_shaderball("plan", spec, "--workers", "0"), f"plan {spec}").stdout
    plan = json.loads(_checked(_shaderball("plan", spec, "--workers", "0", "--json"), f"plan {spec} --json").stdout)
    estimate = next(e for e in plan["estimates"] if e["workers"] == 1 and "--workers 0" in e["where"])
    with tempfile.TemporaryDirectory(prefix="plan-check-") as tmp:
        out = os.path.join(tmp, "data")
        print(f"building {spec} ({plan['renders']} renders) ...", file=sys.stderr)
        start = time.monotonic()
        build = _checked(_shaderball("build", spec, "--out", out, "--workers", "0", "--json"), f"build {spec}")
        wall = time.monotonic() - start
        disk = _folder_bytes(out)
    return {
        "spec": spec,
        "renders": plan["renders"],
        "load_average_before": round(load, 2),
        "plan_text": text,
        "estimated_seconds": estimate["seconds"],
        "estimated_seconds_idle": plan["timing"]["cpu_seconds_per_render"] * plan["renders"],
        "built_seconds": wall,
        "build": json.loads(build.stdout),
        "estimated_bytes": plan["timing"]["bytes_per_render"] * plan["renders"],
        "built_bytes": disk,
    }


def page(rows: list[dict], command: str) -> str:
    lines = [
        head("How close `shaderball plan` comes to the build", command).rstrip("\n"),
        "",
        "Each spec planned with `shaderball plan SPEC --workers 0`, then built with `shaderball build SPEC "
        "--workers 0` (the whole command timed, start-up included); disk is every file of the built folder. "
        "Ratio: built / estimated.",
        "",
        "| spec | renders | load average before | estimated time | built in | ratio | estimated disk | "
        "built disk | ratio |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| `{r['spec']}` | {r['renders']:,} | {r['load_average_before']} | {r['estimated_seconds']:.1f} s | "
            f"{r['built_seconds']:.1f} s | {r['built_seconds'] / r['estimated_seconds']:.2f} | "
            f"{r['estimated_bytes'] / 2**20:.2f} MiB | {r['built_bytes'] / 2**20:.2f} MiB | "
            f"{r['built_bytes'] / r['estimated_bytes']:.2f} |"
        )
    for r in rows:
        lines += ["", f"## `shaderball plan {r['spec']} --workers 0`", "", "```text", r["plan_text"].rstrip(), "```"]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("specs", nargs="+", metavar="SPEC")
    parser.add_argument("--out", required=True, metavar="DIR", help="folder for README.md and plan-check.json")
    args = parser.parse_args(argv)
    if os.path.exists(args.out) and not os.path.isdir(args.out):  # before the plans run: minutes
        parser.error(f"--out: {args.out} exists and is not a folder")
    rows = [check(spec) for spec in args.specs]
    command = shlex.join([".venv/bin/python", "scripts/plan_check.py", *args.specs, "--out", args.out])
    os.makedirs(args.out, exist_ok=True)
    Path(args.out, "README.md").write_text(page(rows, command), encoding="utf-8")
    Path(args.out, "plan-check.json").write_text(json.dumps(rows, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    print(f"wrote {args.out}/README.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
