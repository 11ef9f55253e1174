"""The scale benchmark: every command's wall time and peak memory against the dataset's size.

``shaderball bench [SPEC] --scale 1000,10000,50000 --out docs/results/scale``
    For each size, builds a tiny dataset from SPEC (default ``manifests/paper.toml``: its
    distributions, cut to that many renders, at ``--resolution`` 16 px and ``--spp`` 1) and
    runs every command over it, each as a child process of its own: build, info, validate
    --fast, validate, preview, publish, verify, unpack, the training loader's open and one
    pass, evaluate's set-up. Each child's wall time and peak resident memory (``wait4``'s
    ``ru_maxrss``: the child and the processes it waited for) are taken. It writes to
    ``--out``: ``README.md`` (headed by the command that wrote it, the machine and the
    date: a table per command and size, each command's growth exponents and its cost per
    render), ``scale.png`` (time and peak memory against size, log-log) and ``scale.json``.
    An unmeasured build of two materials comes first, so the smallest size is not charged
    the machine's first kernel compilation.

Per command: the growth exponent is the slope of a least-squares line through (log size,
log value); the cost per render is the slope of a least-squares line through (size, value):
seconds and bytes per extra render. A command whose memory is bounded by the dataset's
structure has a memory cost per render near zero (the goal: under ~1 KB).
"""

from __future__ import annotations

import dataclasses
import datetime
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field

import numpy as np

from pipeline.bench.build_bench import derive_for
from pipeline.dataset.spec_file import spec_to_toml
from pipeline.errors import ShaderballError
from pipeline.fields.rules import format_value
from pipeline.image.chart import BLUE, GREEN, GREY, ORANGE, PURPLE, RED, chart, png
from pipeline.render.mitsuba_env import cpu_model
from pipeline.run.out_folder import read_spec_text
from pipeline.store.atomic import write_bytes_atomic, write_text_atomic
from pipeline.store.records import dumps

#: The repository root: where ``python -m cli`` runs (and the default spec lives).
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEFAULT_SPEC = os.path.join("manifests", "paper.toml")
#: The script that measures the neural stage's opening of a dataset in a process of its own.
OPEN_PROBE = os.path.join(ROOT, "scripts", "open_probe.py")
#: Memory per extra render a command may take and still count as bounded by structure.
MEMORY_GOAL_BYTES_PER_RENDER = 1024
#: The size the page extrapolates each command's peak memory to (a million renders: the scale the
#: goal of under 2 GB is stated at), from the largest size measured and the memory cost per render.
EXTRAPOLATED_RENDERS = 1_000_000


def _commands(data: str, pub: str, work: str) -> list[tuple[str, list[str]]]:
    """(name, argv after the Python interpreter) of every measured command but the build, in order."""
    cli = ["-m", "cli"]
    return [
        ("info", [*cli, "info", data]),
        ("validate --fast", [*cli, "validate", data, "--fast"]),
        ("validate", [*cli, "validate", data]),
        ("preview", [*cli, "preview", data, "--out", os.path.join(work, "preview.png")]),
        ("publish", [*cli, "publish", data, "--out", pub]),
        ("verify", [*cli, "verify", pub]),
        ("unpack", [*cli, "unpack", pub, "--out", os.path.join(work, "unpacked")]),
        ("loader (open + one pass)", [OPEN_PROBE, "loader", data]),
        ("evaluate set-up", [OPEN_PROBE, "evaluate-setup", data]),
    ]


COMMANDS = ("build", *(name for name, _ in _commands("D", "P", "W")))


@dataclass
class Measured:
    command: str
    renders: int
    wall_s: float
    peak_rss_bytes: int


@dataclass
class ScaleBench:
    command_line: str
    spec_name: str
    resolution: int
    spp: int
    sizes: list[int]
    machine: dict
    date: str
    rows: list[Measured] = field(default_factory=list)

    def series(self, command: str) -> list[Measured]:
        return sorted((r for r in self.rows if r.command == command), key=lambda r: r.renders)

    def fit(self, command: str) -> dict:
        """Growth exponents (log-log slopes) and costs per render (linear slopes) of ``command``."""
        rows = self.series(command)
        n = np.array([r.renders for r in rows], float)
        t = np.array([r.wall_s for r in rows], float)
        m = np.array([r.peak_rss_bytes for r in rows], float)
        if len(rows) < 2 or len(set(n)) < 2:
            return {}
        return {
            "time_exponent": _slope(np.log(n), np.log(np.maximum(t, 1e-9))),
            "memory_exponent": _slope(np.log(n), np.log(np.maximum(m, 1.0))),
            "seconds_per_render": _slope(n, t),
            "bytes_per_render": _slope(n, m),
        }

    def extrapolated_peak(self, command: str, renders: int = EXTRAPOLATED_RENDERS) -> float | None:
        """Peak bytes of ``command`` at ``renders``: the largest size's peak plus the memory cost per
        render times the renders beyond it (an extrapolation, not a measurement); a negative cost
        (a peak that fell with size, the allocator's spread) counts as none."""
        fit = self.fit(command)
        if not fit:
            return None
        largest = self.series(command)[-1]
        return largest.peak_rss_bytes + max(fit["bytes_per_render"], 0.0) * (renders - largest.renders)

    def bounded(self, command: str) -> bool | None:
        fit = self.fit(command)
        return fit["bytes_per_render"] < MEMORY_GOAL_BYTES_PER_RENDER if fit else None

    def to_dict(self) -> dict:
        return {
            "command": self.command_line,
            "spec": self.spec_name,
            "resolution": self.resolution,
            "spp": self.spp,
            "sizes": self.sizes,
            "machine": self.machine,
            "date": self.date,
            "memory_goal_bytes_per_render": MEMORY_GOAL_BYTES_PER_RENDER,
            "rows": [dataclasses.asdict(r) for r in self.rows],
            "fits": {c: self.fit(c) for c in COMMANDS if self.series(c)},
        }

    def lines(self) -> list[str]:
        """The summary a command prints: one line per command."""
        out = [
            f"scale benchmark: {self.spec_name} at {self.resolution} px, {self.spp} spp; sizes "
            f"{', '.join(str(s) for s in self.sizes)} renders"
        ]
        for c in COMMANDS:
            fit = self.fit(c)
            if not fit:
                continue
            largest = self.series(c)[-1]
            out.append(
                f"{c:26s} {largest.wall_s:8.2f} s {largest.peak_rss_bytes / 2**20:8.1f} MB at {largest.renders}; "
                f"time ~n^{fit['time_exponent']:.2f} ({fit['seconds_per_render'] * 1e3:.2f} ms/render), "
                f"memory ~n^{fit['memory_exponent']:.2f} ({fit['bytes_per_render'] / 1024:.2f} KB/render)"
            )
        return out

    def markdown(self) -> str:
        m = self.machine
        out = [
            "# Every command's cost against the dataset's size",
            "",
            f"Written by `{self.command_line}` on {self.date}.",
            "",
            f"Machine: {m.get('cpu_model', '?')} ({m.get('cpus', '?')} CPUs, {m.get('memory_gb', '?')} GB), "
            f"{m.get('system', '?')}, Python {m.get('python', '?')}; load average before the run "
            f"{m.get('load_before', '?')}, after {m.get('load_after', '?')}.",
            "",
            f"Datasets: `{self.spec_name}`'s distributions cut to each size, {self.resolution}x{self.resolution} px, "
            f"{self.spp} spp; every command a child process of its own; wall time, and peak resident memory "
            "(`ru_maxrss` of the child and what it waited for). Growth exponent: the slope of a least-squares "
            "line through (log size, log value); per render: the slope of a least-squares line through "
            f"(size, value). Memory bounded by structure: under {MEMORY_GOAL_BYTES_PER_RENDER / 1024:.0f} KB "
            f"per extra render. Peak at {EXTRAPOLATED_RENDERS:,} renders: the largest size's peak plus the "
            "memory cost per render (none where negative) times the renders beyond it, extrapolated, not measured.",
            "",
            *self._load_note(),
            "![time and peak memory against size](scale.png)",
            "",
            "## Growth",
            "",
            "| command | time exponent | ms per render | memory exponent | KB per render | bounded | "
            f"peak at {EXTRAPOLATED_RENDERS:,} renders |",
            "|---|---|---|---|---|---|---|",
        ]
        for c in COMMANDS:
            fit = self.fit(c)
            if fit:
                out.append(
                    f"| {c} | {fit['time_exponent']:.2f} | {fit['seconds_per_render'] * 1e3:.3f} | "
                    f"{fit['memory_exponent']:.2f} | {fit['bytes_per_render'] / 1024:.2f} | "
                    f"{'yes' if self.bounded(c) else 'no'} | {self.extrapolated_peak(c) / 2**30:.2f} GB |"
                )
        out += ["", "## Measured", "", "| command | " + " | ".join(f"{s:,} renders" for s in self.sizes) + " |"]
        out.append("|---|" + "---|" * len(self.sizes))
        for c in COMMANDS:
            by_size = {r.renders: r for r in self.series(c)}
            if not by_size:
                continue
            cells = [
                f"{by_size[s].wall_s:.2f} s, {by_size[s].peak_rss_bytes / 2**20:.0f} MB" if s in by_size else "-"
                for s in self.sizes
            ]
            out.append(f"| {c} | " + " | ".join(cells) + " |")
        return "\n".join(out) + "\n"

    def _load_note(self) -> list[str]:
        """A warning where other work ran beside the benchmark (load above the CPU count)."""
        cpus = self.machine.get("cpus") or 1
        loads = []
        for key in ("load_before", "load_after"):
            try:
                loads += [float(x) for x in str(self.machine.get(key, "")).split()]
            except ValueError:
                pass
        if not loads or max(loads) <= cpus:
            return []
        return [
            f"Other work ran beside this run (load average up to {max(loads):.1f} on {cpus} CPUs): its wall "
            "times, and the time exponents and costs fitted to them, are the machine's load as much as the "
            "commands'; peak memory does not depend on it.",
            "",
        ]

    @classmethod
    def from_dict(cls, doc: dict) -> ScaleBench:
        """A bench from its ``scale.json`` (to write its page again)."""
        return cls(
            command_line=doc["command"],
            spec_name=doc["spec"],
            resolution=doc["resolution"],
            spp=doc["spp"],
            sizes=list(doc["sizes"]),
            machine=dict(doc["machine"]),
            date=doc["date"],
            rows=[Measured(**row) for row in doc["rows"]],
        )

    def figure_png(self) -> bytes:
        colours = [BLUE, RED, GREEN, ORANGE, PURPLE, GREY, (23, 190, 207), (188, 189, 34), (140, 86, 75), (0, 0, 0)]
        time_series, memory_series = [], []
        for c, colour in zip(COMMANDS, colours):
            rows = self.series(c)
            time_series.append((c, colour, [(r.renders, r.wall_s) for r in rows]))
            memory_series.append((c, colour, [(r.renders, r.peak_rss_bytes / 2**20) for r in rows]))
        size = dict(width=900, height=520)
        return png(
            chart(time_series, "wall time (s) against renders, log-log", "renders (log)", True, True, **size),
            chart(memory_series, "peak memory (MB) against renders, log-log", "renders (log)", True, True, **size),
        )


def _slope(x: np.ndarray, y: np.ndarray) -> float:
    return float(np.polyfit(x, y, 1)[0])


def machine_facts() -> dict:
    facts = {
        "system": f"{platform.system()} {platform.release()} {platform.machine()}",
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "cpu_model": cpu_model(),
        "load_before": _load(),
    }
    try:
        with open("/proc/meminfo", encoding="utf-8") as f:
            kb = next(int(ln.split()[1]) for ln in f if ln.startswith("MemTotal"))
        facts["memory_gb"] = round(kb / 2**20, 1)
    except (OSError, StopIteration, ValueError):
        pass
    return facts


def _load() -> str:
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "?"


def measure_child(argv: list[str], log_path: str) -> tuple[float, int]:
    """Run ``python argv`` in the repository root; (wall seconds, peak RSS bytes). A failure is
    raised with its command, exit code and the end of its output."""
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    with open(log_path, "wb") as log:
        start = time.perf_counter()
        child = subprocess.Popen([sys.executable, *argv], cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
        _pid, status, usage = os.wait4(child.pid, 0)
        wall = time.perf_counter() - start
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode != 0:
        with open(log_path, "rb") as f:
            tail = f.read()[-2000:].decode("utf-8", "replace")
        raise ShaderballError(
            f"scale benchmark: `python {' '.join(argv)}` exited with {child.returncode}; its output ends:\n{tail}"
        )
    return wall, int(usage.ru_maxrss) * 1024  # Linux: kilobytes


def run_scale_bench(request, progress=None) -> ScaleBench:
    """Build a dataset of each of ``request.scale``'s sizes and measure every command over it;
    write the results to ``request.out``."""
    out, sizes = request.out, sorted(request.scale)
    resolution, spp = request.settings()
    spec_arg = request.spec or DEFAULT_SPEC
    spec, _ = read_spec_text(request.spec or os.path.join(ROOT, DEFAULT_SPEC))
    smallest = 2 * spec.dataset.lights_per_material  # evaluate holds whole materials out: two at least
    for size in sizes:
        if size < smallest:
            raise request.field_error(
                "scale",
                size,
                f"at least {smallest} renders with this spec (two materials of "
                f"{spec.dataset.lights_per_material} lightings: evaluate's set-up holds materials out)",
            )
    # every size's spec before anything runs: a size the spec cannot hold is refused as --scale
    warm = derive_for(request, spec, renders=smallest, resolution=resolution, spp=spp)
    derived = {
        size: derive_for(request, spec, {"renders": "scale"}, renders=size, resolution=resolution, spp=spp)
        for size in sizes
    }
    if os.path.exists(out) and not os.path.isdir(out):
        raise request.field_error("out", out, "a folder for the results page", what=f"{format_value(out)} is a file")
    say = progress or (lambda message: None)
    command_line = (
        f"shaderball bench {spec_arg} --scale {','.join(str(s) for s in sizes)} "
        f"--resolution {resolution} --spp {spp} --out {out}"
    )
    bench = ScaleBench(
        command_line=command_line,
        spec_name=spec.dataset.name,
        resolution=resolution,
        spp=spp,
        sizes=[],
        machine=machine_facts(),
        date=datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
    )
    scratch = tempfile.mkdtemp(prefix="shaderball-scale-")
    try:
        # An unmeasured build of two materials first: kernels compiled and cached, so the
        # smallest size is not charged the machine's first compilation.
        say("warm-up: a build of two materials ...")
        run_commands(warm, scratch, "warm-up", commands=("build",))
        for size in sizes:
            renders = derived[size].dataset.materials * derived[size].dataset.lights_per_material
            bench.sizes.append(renders)
            for name, wall, peak in run_commands(derived[size], scratch, str(size), say):
                bench.rows.append(Measured(name, renders, wall, peak))
        bench.machine["load_after"] = _load()
        write_results(bench, out)
        return bench
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def run_commands(spec, scratch: str, name: str, say=None, commands=COMMANDS) -> list[tuple[str, float, int]]:
    """Build ``spec`` in ``scratch/name`` and run ``commands`` (every one by default) over it:
    (command, wall s, peak bytes) each. The folder is removed afterwards (the largest sizes
    take disk: one at a time)."""
    say = say or (lambda message: None)
    work = os.path.join(scratch, name)
    os.mkdir(work)
    try:
        spec_file = os.path.join(work, "spec.toml")
        write_text_atomic(spec_file, spec_to_toml(spec))
        data, pub = os.path.join(work, "dataset"), os.path.join(work, "publication")
        renders = spec.dataset.materials * spec.dataset.lights_per_material
        steps = [("build", ["-m", "cli", "build", spec_file, "--out", data, "--workers", "0"])]
        measured = []
        for command, argv in steps + _commands(data, pub, work):
            if command not in commands:
                continue
            say(f"{renders} renders: {command} ...")
            measured.append((command, *measure_child(argv, os.path.join(work, "log.txt"))))
        return measured
    finally:
        shutil.rmtree(work, ignore_errors=True)


def write_results(bench: ScaleBench, out: str) -> None:
    """README.md, scale.png and scale.json into ``out`` (created if needed)."""
    os.makedirs(out, exist_ok=True)
    write_text_atomic(os.path.join(out, "README.md"), bench.markdown())
    write_bytes_atomic(os.path.join(out, "scale.png"), bench.figure_png())
    write_text_atomic(os.path.join(out, "scale.json"), dumps(bench.to_dict()) + "\n")
