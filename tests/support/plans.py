"""Golden plan digests: values that hold on every machine.

A plan is a function of the spec alone (plan format 2, docs/spec.md "The same plan on every
machine"), so its digest is the same on any x86-64 or aarch64 machine with any supported
numpy: tests/test_portable_plan.py proves it here under numpy's CPU-dispatch limits and
the scalar path, and every CI machine checks these values again. A change to them is a
change of the plan format (pipeline.dataset.plan.PLAN_FORMAT), never a machine's doing.
"""

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SMOKE = REPO / "manifests" / "smoke.toml"
PAPER = REPO / "manifests" / "paper.toml"

PLAN_DIGESTS = {
    SMOKE: "0bd27b0915cc03471c2ab2bfc202cb442cd655692f8e8cc21813529df54ba097",
    PAPER: "02497a40fe656508735288005e9f799eaecd53c62acbfc052556362abda90d3b",
}
