"""`shaderball study`'s request: what is measured (configurations, draws, references,
repeats), checked when made and against the spec, recorded in the study folder so that a
re-run resumes the same study and another request is refused. :mod:`pipeline.study.run`
runs it.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import asdict, dataclass

from pipeline.dataset.spec_file import parse_spec, spec_digest, spec_operand
from pipeline.fields import Checked, field, same_as
from pipeline.fields.rules import Bool, Int, IntList, Optional, Reject, Rule, StrList, format_value
from pipeline.fields.rules import Path as PathRule
from pipeline.render.mitsuba_env import machine_fingerprint
from pipeline.render.renderer import (
    RenderSettings,
)
from pipeline.study.configs import DEFAULT_LADDER, FAMILIES, study_configs

REQUEST_FILE = "request.json"
MAX_LADDER_SPP = 16384
#: Samples drawn from the plan.
DRAWS_RANGE = (1, 1000)
#: The largest spp of a reference.
MAX_REFERENCE_SPP = 65536
MAX_REPEATS = 64


class Ladder(IntList):
    """The spp ladder: integers from 1 to MAX_LADDER_SPP, kept sorted and once each."""

    def __init__(self):
        super().__init__(1, MAX_LADDER_SPP)

    def check(self, value):
        return tuple(sorted(set(super().check(value))))


class EvenInt(Int):
    """An even integer from ``lo`` to ``hi`` (a reference renders as two equal halves)."""

    def __init__(self, lo: int, hi: int):
        super().__init__(lo, hi)
        self.allowed = f"an even integer from {lo} to {hi}"

    def check(self, value):
        value = super().check(value)
        if value % 2:
            raise Reject()
        return value

    @property
    def brief(self) -> str:
        return f"even, {self.lo} to {self.hi}"


class Families(Rule):
    """Families of configurations: ``all``, or names from FAMILIES; kept in FAMILIES' order,
    the ladder always among them."""

    allowed = "all, or comma-separated names from " + ", ".join(FAMILIES)
    metavar = "all|NAME,..."

    def parse(self, text: str):
        text = text.strip()
        return text if text == "all" else tuple(word.strip() for word in text.split(","))

    def check(self, value):
        if value == "all":
            return FAMILIES
        if isinstance(value, str) or not isinstance(value, (list, tuple)) or not value:
            raise Reject()
        if not all(isinstance(name, str) and name in FAMILIES for name in value):
            raise Reject()
        return tuple(f for f in FAMILIES if f in value or f == "ladder")

    @property
    def brief(self) -> str:
        return "all, or names from " + ", ".join(FAMILIES)


@dataclass(frozen=True)
class StudyRequest(Checked):
    """What `shaderball study` is asked; each field declared once (pipeline.fields)."""

    spec: str = spec_operand()
    out: str = field(
        rule=PathRule("a folder"),
        doc="Study folder: request.json, references/, rows/, then study.json, study.csv, pareto.png, "
        "report.md. Re-running the same command resumes; another request is refused.",
        metavar="DIR",
    )
    draws: int = field(
        12,
        rule=Int(*DRAWS_RANGE),
        doc="Samples drawn from the spec's plan, spread over material classes, sun, turbidity and roughness.",
        unit="draws",
    )
    reference_spp: int = field(
        4096,
        rule=EvenInt(2, MAX_REFERENCE_SPP),
        doc="Samples per pixel of each reference (two halves); at least twice the largest of {ladder} and the "
        f"spec's render.spp ({2 * max(DEFAULT_LADDER)} with the default {{ladder}}).",
        unit="samples per pixel",
    )
    resolution: int | None = same_as(RenderSettings, "resolution", unset="the spec's")
    ladder: tuple[int, ...] = field(
        DEFAULT_LADDER,
        rule=Ladder(),
        doc="spp ladder of the independent sampler (the spec's spp is always added).",
    )
    configs: tuple[str, ...] | str = field(
        "all", rule=Families(), doc="Families of configurations (the ladder is always measured)."
    )
    only: tuple[str, ...] | None = field(
        None,
        rule=Optional(StrList(None, "configuration names"), "unset (every configuration of the families)"),
        doc="Only these configurations (comma-separated names as the report writes them, e.g. "
        "multijitter/64); the spec's recipe is always measured.",
        metavar="NAMES",
    )
    repeats: int = field(
        3,
        rule=Int(1, MAX_REPEATS),
        doc="Independent seeds per sample and configuration (the cost grows in proportion); "
        "every figure carries a 95% interval over samples and seeds.",
        unit="seeds",
    )
    flip: bool = field(True, rule=Bool(), doc="HDR-FLIP (the slowest metric).")
    #: Not on the command line: the study's selection scans this many materials.
    scan: int = field(60, rule=Int(1, 100000), doc="Materials of the plan whose lightings are candidates.")


@dataclass
class StudySummary:
    out: str
    samples: int
    configs: int
    rows: int
    rendered: int
    reused: int
    seconds: float
    recommendations: dict = dataclasses.field(default_factory=dict)

    def lines(self) -> list[str]:
        out = [
            f"study: {self.samples} samples x {self.configs} configurations = {self.rows} rows "
            f"({self.rendered} measured now, {self.reused} kept) in {self.seconds:.0f} s",
            f"wrote {self.out}/study.json, study.csv, pareto.png, report.md",
        ]
        for key, rec in self.recommendations.items():
            if rec:
                out.append(f"{key}: {rec['config']} ({rec['note']})")
        return out

    def to_dict(self) -> dict:
        return asdict(self)


def check_request(req: StudyRequest):
    """The parsed spec; a refusal names the field, its value and what is allowed."""
    spec = parse_spec(req.spec)
    if req.only:
        names = [
            c.name
            for c in study_configs(spec.render.spp, spec.lighting.sun, req.ladder, req.configs, spec.render.max_depth)
        ]
        unknown = [n for n in req.only if n not in names]
        if unknown:
            raise req.field_error(
                "only",
                req.only,
                "comma-separated configuration names of the chosen {configs} and {ladder} "
                f"(unknown: {', '.join(unknown)}), e.g. " + ", ".join(names[:4]),
            )
    top = max(*req.ladder, spec.render.spp)
    if req.reference_spp < 2 * top:
        raise req.field_error(
            "reference_spp",
            req.reference_spp,
            f"an even integer from {2 * top} to {MAX_REFERENCE_SPP} here: at least twice the largest spp studied, "
            f"the largest of {{ladder}} ({max(req.ladder)}) and {req.spec}'s render.spp ({spec.render.spp})",
        )
    if os.path.exists(req.out) and not os.path.isdir(req.out):
        raise req.field_error("out", req.out, "a folder (new, or a study folder of this same request)")
    return spec


def request_record(req: StudyRequest, spec) -> dict:
    return {
        "spec_digest": spec_digest(spec),
        "samples": req.draws,
        "reference_spp": req.reference_spp,
        "resolution": req.resolution or spec.render.resolution,
        "ladder": list(req.ladder),
        "families": list(req.configs),
        "scan": req.scan,
        "flip": req.flip,
        "repeats": req.repeats,
        **({"only": list(req.only)} if req.only else {}),
    }


def machine_line(variant: str) -> str:
    """The machine a study ran on, as its report's heading names it."""
    cpu = machine_fingerprint()
    return f"{cpu['cpu_model']} ({os.cpu_count()} CPUs, {cpu['arch']}), Mitsuba variant {variant}"


def check_resumable(req: StudyRequest, record: dict) -> None:
    """Refuse ``req.out`` where it holds anything but a study of this same request."""
    out = req.out
    path = os.path.join(out, REQUEST_FILE)
    if not os.path.isdir(out) or not os.listdir(out):
        return
    if not os.path.exists(path):
        raise req.field_error("out", out, "an empty or new folder, or a study folder (holding request.json)")
    with open(path, encoding="utf-8") as fh:
        old = json.load(fh)
    diff = sorted(k for k in set(old) | set(record) if old.get(k) != record.get(k))
    if diff:
        raise req.field_error(
            "out",
            out,
            "use a new folder, or the same spec and options to resume",
            what=f"{format_value(out)} holds a study of another request (differs in {', '.join(diff)})",
        )
