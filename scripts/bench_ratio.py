"""Build-level time of one spec against another, from `shaderball bench --json` files.

    python scripts/bench_ratio.py BASELINE.json CANDIDATE.json [CANDIDATE.json ...]

prints, per candidate, its build's CPU time over the baseline build's (both builds of the
same number of renders, this process and its reaped children: the time a build spends
per render, scene load, storage and kernel compilation included) and the same ratio for
the bare renders alone. docs/accuracy.md quotes these lines.
"""

from __future__ import annotations

import json
import os
import sys


def ratio_lines(baseline: dict, candidates: list[tuple[str, dict]]) -> list[str]:
    out = []
    for name, c in candidates:
        if c["samples"] != baseline["samples"]:
            raise SystemExit(f"{name}: {c['samples']} renders, the baseline {baseline['samples']}: not comparable")
        out.append(
            f"{name}: {c['spec_name']} / {baseline['spec_name']}, {c['samples']} renders at "
            f"{c['resolution']}x{c['resolution']}: build CPU {c['build_cpu_s']:.1f} s / {baseline['build_cpu_s']:.1f} s "
            f"= {c['build_cpu_s'] / baseline['build_cpu_s']:.2f}x; bare renders {c['bare_cpu_s']:.1f} s / "
            f"{baseline['bare_cpu_s']:.1f} s = {c['bare_cpu_s'] / baseline['bare_cpu_s']:.2f}x; kernels compiled "
            f"during the build {c.get('build_compiled')} (baseline {baseline.get('build_compiled')})"
        )
    return out


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    with open(argv[0], encoding="utf-8") as fh:
        baseline = json.load(fh)
    candidates = []
    for path in argv[1:]:
        with open(path, encoding="utf-8") as fh:
            candidates.append((os.path.basename(path), json.load(fh)))
    print("\n".join(ratio_lines(baseline, candidates)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
