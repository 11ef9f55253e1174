#!/usr/bin/env python3
"""Crash test: SIGKILL `shaderball build` at random moments, resume, repeat, check everything.

    .venv/bin/python scripts/crash_test.py --kills 100            # the run reported in docs/resume.md
    .venv/bin/python scripts/crash_test.py --kills 20 --seed 7 --dask-every 5 --keep

Each *trial* builds the spec into a fresh directory. An *attempt* starts ``shaderball build``
in a new session (so the whole process tree, dask workers included, is one process group)
and kills the group with SIGKILL in one of three ways:

- ``timer``: after a delay drawn uniformly over an uninterrupted build's duration (``--workers 0``);
- ``write``: at an exact point inside the N-th atomic write of one kind of file (EXR, sample
  record, shard marker, manifest, description, spec snapshot): half the bytes written, before
  the fsync, before the rename, or after the rename but before the caller goes on. The child
  patches :mod:`pipeline.store.atomic` (only in its own process) and kills its group itself;
- ``dask``: a build on a local dask cluster of 2 worker processes, killed a random delay
  after its worker processes exist.

After every kill the directory is checked (:func:`check_interrupted`): no process of the
group is left, every file other than ``.tmp-*`` temporaries is whole and byte-identical to
the reference build (JSON compared without run timings), every record and marker agrees with
the reference. Then the next attempt resumes. When an attempt completes, the dataset must be
exactly the reference (:func:`check_complete`: same files, EXRs byte-identical, manifest in
plan order with unique ids, no temporary file left) and ``validate`` must pass.

SIGKILL tests a process crash, not a power cut: data the kernel accepted survives.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import fcntl
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SMOKE_SPEC = REPO / "manifests" / "smoke.toml"
#: Kinds of files the build writes atomically, by name.
KINDS = ("exr", "record", "marker", "manifest", "description", "spec")
#: Points inside one atomic write where a ``write`` attempt kills the process group.
PHASES = ("write", "fsync", "rename", "renamed")
NOTE_ENV = "SHADERBALL_CRASH_NOTE"


def file_kind(path: str) -> str:
    from pipeline.store.folder import is_record_file
    from pipeline.store.layout import DESCRIPTION_FILE, MANIFEST_FILE, MARKER_FILE, SPEC_FILE

    name = os.path.basename(path)
    if name.endswith(".exr"):
        return "exr"
    if name == MARKER_FILE:
        return "marker"
    if is_record_file(name):
        return "record"
    return {MANIFEST_FILE: "manifest", DESCRIPTION_FILE: "description", SPEC_FILE: "spec"}.get(name, "other")


# --------------------------------------------------------------------------- the child side


def install_write_hook(kind: str, nth: int, phase: str, note_path: str | None) -> None:
    """Kill this process group inside the ``nth`` atomic write of a ``kind`` file, at ``phase``.

    Patches only :mod:`pipeline.store.atomic`'s view of ``os`` and its functions, before the rest
    of the package imports them, so the real write code runs up to the kill point.
    """
    import pipeline.store.atomic as atomic

    state = {"seen": 0, "armed": False, "path": None}
    real_fsync_dir = atomic.fsync_dir

    def die(where: str) -> None:
        if note_path:
            with open(note_path, "a", encoding="utf-8") as fh:
                fh.write(json.dumps({"kind": kind, "nth": nth, "phase": where, "path": state["path"]}) + "\n")
                fh.flush()
                os.fsync(fh.fileno())
        os.killpg(os.getpgrp(), signal.SIGKILL)

    class TornFile:
        def __init__(self, fh):
            self._fh = fh

        def write(self, data):
            self._fh.write(data[: len(data) // 2])
            self._fh.flush()
            die("write")

        def __getattr__(self, name):
            return getattr(self._fh, name)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return self._fh.__exit__(*exc)

    class OsProxy:
        def __getattr__(self, name):
            return getattr(os, name)

        def fdopen(self, fd, *args, **kwargs):
            fh = os.fdopen(fd, *args, **kwargs)
            return TornFile(fh) if state["armed"] and phase == "write" else fh

        def fsync(self, fd):
            if state["armed"] and phase == "fsync":
                die("fsync")
            return os.fsync(fd)

        def replace(self, src, dst):
            if state["armed"] and phase == "rename":
                die("rename")
            return os.replace(src, dst)

    def fsync_dir(path):
        if state["armed"] and phase == "renamed":
            die("renamed")
        return real_fsync_dir(path)

    real_atomic_file = atomic.atomic_file

    @contextlib.contextmanager
    def atomic_file(path, *args, **kwargs):  # the one atomic writer: whole files and streamed ones alike
        if file_kind(path) == kind:
            state["seen"] += 1
            state["armed"] = state["seen"] == nth
            state["path"] = "/".join(Path(path).parts[-2:])
        try:
            with real_atomic_file(path, *args, **kwargs) as fh:
                yield fh
        finally:
            state["armed"] = False

    atomic.os = OsProxy()
    atomic.fsync_dir = fsync_dir
    atomic.atomic_file = atomic_file


def child_main(argv: list[str]) -> None:
    """``crash_test.py --child [--hook KIND:N:PHASE] -- build ARGS...``: the CLI, maybe hooked."""
    sys.path.insert(0, str(REPO))
    hook = None
    if argv and argv[0] == "--hook":
        hook, argv = argv[1], argv[2:]
    if argv and argv[0] == "--":
        argv = argv[1:]
    if hook:
        kind, nth, phase = hook.split(":")
        install_write_hook(kind, int(nth), phase, os.environ.get(NOTE_ENV))
    import cli

    cli.main(args=argv, prog_name="shaderball")


# --------------------------------------------------------------------------- processes


def child_command(spec: Path, out: Path, workers: int, hook: str | None = None) -> list[str]:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child"]
    if hook:
        cmd += ["--hook", hook]
    return cmd + ["--", "build", str(spec), "--out", str(out), "--workers", str(workers)]


def group_members(pgid: int) -> list[int]:
    """Live (non-zombie) processes of process group ``pgid``."""
    members = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", encoding="ascii", errors="replace") as fh:
                stat = fh.read()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        if int(fields[2]) == pgid and fields[0] != "Z":
            members.append(int(entry))
    return members


def kill_group(proc: subprocess.Popen, timeout_s: float = 20.0) -> int:
    """SIGKILL the process group of ``proc`` (a session leader), wait until it is gone;
    return how many processes it had."""
    members = len(group_members(proc.pid))
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=timeout_s)
    deadline = time.monotonic() + timeout_s
    while group_members(proc.pid):
        if time.monotonic() > deadline:
            raise AssertionError(f"processes of group {proc.pid} survived SIGKILL: {group_members(proc.pid)}")
        time.sleep(0.05)
    return members


@dataclasses.dataclass
class Attempt:
    mode: str  # timer | write | dask | none
    detail: str
    killed: bool
    returncode: int
    seconds: float
    temp_files: int = 0
    note: dict | None = None
    #: processes in the group when a timer or dask kill was sent (workers included).
    group_size: int = 0


def run_attempt(
    spec: Path,
    out: Path,
    mode: str,
    logs: Path,
    *,
    delay_s: float = 0.0,
    hook: str | None = None,
    timeout_s: float = 600.0,
) -> Attempt:
    """One build; killed per ``mode`` ('none' lets it finish). The group is always gone after."""
    logs.mkdir(parents=True, exist_ok=True)
    note = logs / "note.jsonl"
    note.unlink(missing_ok=True)
    env = dict(os.environ, **{NOTE_ENV: str(note)})
    workers = 2 if mode == "dask" else 0
    log = open(logs / "attempt.log", "ab")
    start = time.monotonic()
    group_size = 0
    proc = subprocess.Popen(
        child_command(spec, out, workers, hook if mode == "write" else None),
        cwd=REPO,
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        if mode == "dask":
            # The delay counts from the moment the worker processes exist (client, resource
            # tracker, 2 workers), so the kill lands with workers in the tree whatever the
            # cluster's start-up time.
            deadline = time.monotonic() + 120
            while proc.poll() is None and len(group_members(proc.pid)) < 4 and time.monotonic() < deadline:
                time.sleep(0.05)
        if mode in ("timer", "dask"):
            try:
                proc.wait(timeout=delay_s)
            except subprocess.TimeoutExpired:
                group_size = kill_group(proc)
        else:
            proc.wait(timeout=timeout_s)
    finally:
        if proc.poll() is None or group_members(proc.pid):
            kill_group(proc)
        log.close()
    seconds = time.monotonic() - start
    killed = proc.returncode == -signal.SIGKILL
    detail = hook if mode == "write" else (f"{delay_s:.2f}s" if mode in ("timer", "dask") else "")
    noted = None
    if note.exists():
        lines = note.read_text().splitlines()
        noted = json.loads(lines[-1]) if lines else None
    return Attempt(mode, detail, killed, proc.returncode, seconds, note=noted, group_size=group_size)


# --------------------------------------------------------------------------- reference and checks


def without_timings(obj):
    """A record, marker or manifest line minus run-dependent values (render time)."""
    from pipeline.store.records import RUN_DEPENDENT_STATS

    if isinstance(obj, dict):
        out = {k: without_timings(v) for k, v in obj.items()}
        if isinstance(obj.get("stats"), dict):
            out["stats"] = {k: v for k, v in obj["stats"].items() if k not in RUN_DEPENDENT_STATS}
        return out
    if isinstance(obj, list):
        return [without_timings(v) for v in obj]
    return obj


def dataset_files(root: Path) -> dict[str, Path]:
    """rel path -> path of every file under ``root`` (temporary files included)."""
    out = {}
    for folder, _dirs, names in os.walk(root):
        for name in names:
            path = Path(folder) / name
            out[path.relative_to(root).as_posix()] = path
    return out


def ensure_reference(dest: Path, spec: Path = SMOKE_SPEC) -> float:
    """An uninterrupted in-process build of ``spec`` in ``dest`` (built once; a lock keeps
    concurrent test processes from building it twice). Return its build time in seconds."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    with open(str(dest) + ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        timing = Path(str(dest) + ".seconds")
        if (dest / "manifest.jsonl").exists() and timing.exists():
            return float(timing.read_text())
        shutil.rmtree(dest, ignore_errors=True)
        start = time.monotonic()
        subprocess.run(
            child_command(spec, dest, 0),
            cwd=REPO,
            check=True,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        seconds = time.monotonic() - start
        timing.write_text(f"{seconds:.3f}")
        return seconds


def shared_reference(tmp_path_factory) -> tuple[Path, float]:
    """For pytest: the smoke reference, built once per test session (shared by xdist workers)."""
    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    dest = root / "smoke-reference"
    return dest, ensure_reference(dest)


def _compare_file(rel: str, path: Path, ref: Path, problems: list[str]) -> None:
    kind = file_kind(rel)
    if kind in ("exr", "spec"):
        if path.read_bytes() != ref.read_bytes():
            problems.append(f"{rel}: bytes differ from the reference")
        return
    if kind == "manifest":
        try:
            mine = [json.loads(line) for line in path.read_text().splitlines()]
        except ValueError:
            problems.append(f"{rel}: torn (not JSON lines)")
            return
        theirs = [json.loads(line) for line in ref.read_text().splitlines()]
        if without_timings(mine) != without_timings(theirs):
            problems.append(f"{rel}: differs from the reference manifest")
        return
    try:
        mine = json.loads(path.read_text())
    except ValueError:
        problems.append(f"{rel}: torn (not JSON)")
        return
    theirs = json.loads(ref.read_text())
    if kind == "description":
        mine, theirs = ({k: v for k, v in d.items() if k != "libraries"} for d in (mine, theirs))
    if without_timings(mine) != without_timings(theirs):
        problems.append(f"{rel}: differs from the reference (timings aside)")


def temp_files(root: Path) -> set[str]:
    from pipeline.store.folder import is_temp_file

    return {rel for rel in dataset_files(root) if is_temp_file(os.path.basename(rel))}


def check_interrupted(out: Path, reference: Path) -> int:
    """Check a directory a kill left behind; return its temporary-file count.

    Every non-temporary file is whole and equal to the reference's (EXRs and the spec
    snapshot byte for byte, JSON without timings), so every record and marker on disk refers
    to durable, correct files; nothing exists that the reference lacks.
    """
    from pipeline.store.folder import is_lock_file, is_temp_file

    problems, temps = [], 0
    ref_files = dataset_files(reference)
    for rel, path in sorted(dataset_files(out).items()):
        if is_temp_file(os.path.basename(rel)):
            temps += 1
            continue
        if is_lock_file(rel):
            continue  # the killed writer's lock file, unlocked by the kernel (pipeline.store.lock)
        if rel not in ref_files:
            problems.append(f"{rel}: not in the reference build")
            continue
        _compare_file(rel, path, ref_files[rel], problems)
    if problems:
        raise AssertionError(f"{out} after a kill:\n  " + "\n  ".join(problems[:20]))
    return temps


def check_complete(out: Path, reference: Path, use_validate: bool = True) -> None:
    """A finished dataset is the reference: same files, same bytes, valid."""
    problems = []
    mine, ref_files = dataset_files(out), dataset_files(reference)
    for rel in sorted(set(mine) ^ set(ref_files)):
        problems.append(f"{rel}: {'extra' if rel in mine else 'missing'}")
    for rel in sorted(set(mine) & set(ref_files)):
        _compare_file(rel, mine[rel], ref_files[rel], problems)
    lines = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]
    ids = [r["id"] for r in lines]
    if len(ids) != len(set(ids)):
        problems.append(f"manifest: duplicate ids {sorted(i for i, n in Counter(ids).items() if n > 1)}")
    from pipeline.dataset.plan import iter_samples, plan_dataset
    from pipeline.dataset.spec_file import parse_spec

    planned = [s.sample_id for s in iter_samples(plan_dataset(parse_spec(out / "spec.toml")))]
    if ids != planned:
        problems.append("manifest: ids are not the plan's, in plan order")
    if use_validate:
        try:
            from pipeline.check.validate import validate
        except ImportError:
            validate = None
        if validate is not None:
            report = validate(str(out))
            if not report.ok:
                problems += [f"validate: {p.kind}: {p.message}" for p in report.problems[:10]]
    if problems:
        raise AssertionError(f"{out} after completion:\n  " + "\n  ".join(problems[:30]))


# --------------------------------------------------------------------------- campaigns


@dataclasses.dataclass
class CampaignResult:
    kills: int
    attempts: list[Attempt]
    trials_completed: int
    seconds: float
    reference_seconds: float

    def counts(self) -> Counter:
        return Counter(a.mode for a in self.attempts if a.killed)

    def write_kinds(self) -> Counter:
        return Counter(
            f"{a.note['kind']}@{a.note['phase']}" for a in self.attempts if a.killed and a.mode == "write" and a.note
        )

    def lines(self) -> list[str]:
        mid_write = sum(1 for a in self.attempts if a.killed and a.temp_files)
        return [
            f"{self.kills} kills (SIGKILL of the whole process group) in {len(self.attempts)} attempts, "
            f"{self.trials_completed} datasets completed, {self.seconds:.0f} s "
            f"(reference build {self.reference_seconds:.1f} s)",
            "kills by mode: " + ", ".join(f"{m} {n}" for m, n in sorted(self.counts().items())),
            "write kills by file@phase: "
            + (", ".join(f"{k} {n}" for k, n in sorted(self.write_kinds().items())) or "none"),
            f"kills that left a temporary file (a write cut mid-way): {mid_write}",
            "processes in the group at dask kills: "
            + (", ".join(str(a.group_size) for a in self.attempts if a.killed and a.mode == "dask") or "none"),
            "result: PASS: every interrupted state consistent; every completed dataset byte-identical "
            "to the reference, no sample lost or duplicated, validate ok",
        ]


def expected_writes(out: Path, reference: Path) -> Counter:
    """How many atomic writes of each kind the next build of ``out`` will at least make."""
    from pipeline.store.folder import is_temp_file

    have = {rel for rel in dataset_files(out) if not is_temp_file(os.path.basename(rel))}
    missing = Counter(file_kind(rel) for rel in dataset_files(reference) if rel not in have)
    return Counter(
        {
            "exr": missing["exr"],
            "record": missing["record"],
            "marker": missing["marker"],
            "spec": missing["spec"],
            "description": 1,
            "manifest": 1,
        }
    )


def random_choice(
    rng: random.Random, dask_due: bool, out: Path, reference: Path, ref_seconds: float, dask_seconds: float
) -> tuple[str, object]:
    """A kill that lands while there is still work to interrupt; a dask one when due and
    a quarter or more of the renders are left (else the cluster never starts)."""
    writes = expected_writes(out, reference)
    left = writes["record"] / max(1, sum(1 for r in dataset_files(reference) if file_kind(r) == "record"))
    if not writes["record"] and not writes["marker"] and rng.random() < 0.5:
        return "none", None  # only the manifest is left: let half of these trials finish
    if dask_due and left >= 0.25:
        # Seconds after the workers exist: their start-up plus the remaining rendering.
        return "dask", rng.uniform(0.0, dask_seconds * (0.3 + 0.7 * left))
    if rng.random() < 0.3:
        return "timer", rng.uniform(0.0, ref_seconds * (0.15 + left))
    # Kinds weighted by how many writes of each are to come: EXRs most often, as in a build.
    kinds = [k for k in KINDS if writes[k] > 0]
    kind = rng.choices(kinds, weights=[writes[k] for k in kinds])[0]
    return "write", f"{kind}:{rng.randint(1, writes[kind])}:{rng.choice(PHASES)}"


def run_campaign(
    kills: int,
    work: Path,
    reference: Path,
    *,
    spec: Path = SMOKE_SPEC,
    seed: int = 0,
    plan=None,
    dask_every: int = 0,
    log=print,
    reference_seconds: float | None = None,
    dask_seconds: float = 12.0,
) -> CampaignResult:
    """Kill builds until ``kills`` kills happened; finish the last trial; check everything.

    ``plan``: explicit (mode, parameter) choices to use first (then random ones). Raises
    AssertionError at the first inconsistency.
    """
    rng = random.Random(seed)
    ref_seconds = reference_seconds if reference_seconds is not None else ensure_reference(reference, spec)
    choices = iter(list(plan or []))
    attempts: list[Attempt] = []
    done_kills, trials, start = 0, 0, time.monotonic()
    since_dask = 0
    out = None
    while done_kills < kills or out is not None:
        if out is None:
            out = work / f"trial{trials:03d}"
            shutil.rmtree(out, ignore_errors=True)
        if done_kills >= kills:
            mode, param = "none", None
        else:
            since_dask += 1
            mode, param = next(choices, None) or random_choice(
                rng, bool(dask_every) and since_dask >= dask_every, out, reference, ref_seconds, dask_seconds
            )
            if mode == "dask":
                since_dask = 0
        delay = float(param) if mode in ("timer", "dask") else 0.0
        temps_before = temp_files(out)
        attempt = run_attempt(spec, out, mode, work / "logs", delay_s=delay, hook=param if mode == "write" else None)
        attempts.append(attempt)
        if attempt.killed:
            done_kills += 1
            check_interrupted(out, reference)
            attempt.temp_files = len(temp_files(out) - temps_before)
            where = f" in {attempt.note['path']} at {attempt.note['phase']}" if attempt.note else ""
            procs = f" ({attempt.group_size} processes)" if attempt.group_size else ""
            log(
                f"kill {done_kills:4d}: {mode} {attempt.detail}{where}{procs} after {attempt.seconds:.1f} s; "
                f"{attempt.temp_files} new temp file(s); state consistent"
            )
        elif attempt.returncode == 0:
            check_complete(out, reference)
            trials += 1
            log(
                f"trial {trials}: completed by a {mode} attempt that was not killed "
                f"({done_kills} kills so far); byte-identical to the reference, validate ok"
            )
            out = None
        else:
            tail = (work / "logs" / "attempt.log").read_text(errors="replace")[-3000:]
            raise AssertionError(f"build exited {attempt.returncode} ({mode} {attempt.detail}):\n{tail}")
    return CampaignResult(done_kills, attempts, trials, time.monotonic() - start, ref_seconds)


#: What a work folder holds once this script has used it (its reference build, the trials'
#: builds and the attempts' logs); the reference and the trials are removed and rebuilt.
WORK_ENTRY = re.compile(r"reference(\.lock|\.seconds)?|trial\d{3,}|logs")


def check_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Every argument checked before anything is written or removed (``parser.error``: exit 2)."""
    from pipeline.dataset.spec_file import parse_spec
    from pipeline.errors import ShaderballError

    if not 1 <= args.kills <= 100_000:
        parser.error(f"--kills: {args.kills} is not allowed; allowed: 1 to 100000")
    if not 0 <= args.seed < 2**63:
        parser.error(f"--seed: {args.seed} is not allowed; allowed: 0 to 2^63-1")
    if args.dask_every < 0:
        parser.error(f"--dask-every: {args.dask_every} is not allowed; allowed: 0 (never) or more")
    try:
        parse_spec(args.spec)
    except (ShaderballError, OSError) as exc:
        parser.error(f"--spec: {exc}")
    work = args.work
    if work is not None and (work.exists() or work.is_symlink()):
        if not work.is_dir() or work.is_symlink():
            parser.error(f"--work: {work} exists and is not a folder")
        foreign = sorted(p.name for p in work.iterdir() if not WORK_ENTRY.fullmatch(p.name))
        if foreign:
            parser.error(
                f"--work: {work} holds {foreign[0]!r}, which this script does not write (its reference "
                "and trials are removed and rebuilt there): name a new or empty folder"
            )


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--child":
        child_main(argv[1:])
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kills", type=int, default=100, help="SIGKILLs to deliver (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="random seed of kill moments (default 0)")
    parser.add_argument(
        "--dask-every",
        type=int,
        default=10,
        help="about every Nth attempt builds on a local dask cluster of 2 workers, when a "
        "quarter of the renders or more are left (default 10; 0: never)",
    )
    parser.add_argument("--spec", type=Path, default=SMOKE_SPEC, help="spec to build (default: smoke)")
    parser.add_argument("--work", type=Path, default=None, help="work folder (default: a new temp folder)")
    parser.add_argument("--keep", action="store_true", help="keep the work folder")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(REPO))
    check_arguments(parser, args)
    work = args.work or Path(tempfile.mkdtemp(prefix="shaderball-crash-"))
    # SIGTERM/SIGINT unwind through run_attempt's cleanup, which kills the child's group.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    try:
        print(f"reference build of {args.spec} in {work / 'reference'} ...", flush=True)
        result = run_campaign(
            args.kills,
            work,
            work / "reference",
            spec=args.spec,
            seed=args.seed,
            dask_every=args.dask_every,
            log=lambda line: print(line, flush=True),
        )
    except AssertionError as exc:
        print(f"result: FAIL: {exc}", flush=True)
        print(f"work folder kept: {work}")
        return 1
    for line in result.lines():
        print(line)
    if args.keep or args.work:
        print(f"work folder: {work}")
    else:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
