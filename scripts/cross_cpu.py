"""What another CPU changes in a dataset: one spec built natively and under emulated CPUs,
compared file by file (pipeline.bench.cross_cpu; docs/build.md).

    .venv/bin/python scripts/cross_cpu.py manifests/smoke.toml --out /tmp/cross-cpu [--json]

writes report.md and report.json into --out (a new folder) and prints the report (markdown,
or with --json the report as one JSON document). About a minute for the smoke spec.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.bench.cross_cpu import child, cross_cpu_report, report_markdown  # noqa: E402
from pipeline.errors import USER_ERRORS  # noqa: E402
from pipeline.fields import FieldError  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="scripts/cross_cpu.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("spec", help="dataset spec (TOML); a small one: manifests/smoke.toml")
    parser.add_argument("out", nargs="?", help=argparse.SUPPRESS)
    parser.add_argument("--out", dest="out_opt", help="folder for the four builds and the report (must not exist)")
    parser.add_argument("--json", action="store_true", help="print the report as JSON only")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--llvm-avx2", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:  # one build of the measurement, in a process of its own
        child(args.spec, args.out, args.llvm_avx2)
        return 0
    if not args.out_opt:
        parser.error("--out is required")
    try:
        result = cross_cpu_report(args.spec, args.out_opt)
    except USER_ERRORS as exc:
        if isinstance(exc, FieldError):  # out, as this script spells it
            exc = exc.labelled(lambda name: "--" + name)
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code
    print(json.dumps(result) if args.json else report_markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
