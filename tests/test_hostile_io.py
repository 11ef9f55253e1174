"""Specs, filesystem errors, machine-readable output and Ctrl-C, with real
processes: a spec read once from a pipe, the plan made lazily (and still the same plan),
a folder made read-only with chattr +i, a full disk (ulimit -f: EFBIG), corrupt EXRs of every
kind under `validate --json`, and SIGINT of a build. Each ends with a one-line message, its
documented exit code, no traceback, and a dataset the same command resumes."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest
from conftest import crash_module

from pipeline.dataset.plan import KIND_SVBRDF, KIND_UNIFORM, plan_dataset, plan_summary
from pipeline.dataset.spec import MAP_LAYERS
from pipeline.dataset.spec_file import parse_spec, parse_spec_bytes
from pipeline.errors import ShaderballError
from pipeline.fields.rules import Reject, StrList
from pipeline.run.out_folder import plan_digest
from support.hostile import copy_dataset
from support.plans import PLAN_DIGESTS
from support.processes import cli, has_mapped, started

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"
PAPER = REPO / "manifests" / "paper.toml"
crash = crash_module()


def run_shell(command: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", "-c", command], cwd=REPO, capture_output=True, text=True, timeout=timeout)


def one_error_line(stderr: str) -> str:
    """The last line of stderr, which must be the error; no traceback anywhere."""
    assert "Traceback" not in stderr, stderr
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert lines and lines[-1].startswith("error: "), stderr
    return lines[-1]


# --------------------------------------------------------------------------- specs


def counted_summary(shards) -> dict:
    """plan_summary by counting the materials of planned shards (what Plan.summary computes
    from its arrays)."""
    materials = [m for shard in shards for m in shard.materials]
    sources = Counter(
        f"family:{m.svbrdf_family}" if m.svbrdf_family is not None else f"folder:{os.path.dirname(m.svbrdf_file)}"
        for m in materials
        if m.kind == KIND_SVBRDF
    )
    return {
        "shards": len(shards),
        "materials": len(materials),
        "renders": sum(m.n_lights for m in materials),
        "uniform": sum(m.kind == KIND_UNIFORM for m in materials),
        "svbrdf": sum(m.kind == KIND_SVBRDF for m in materials),
        "svbrdf_sources": dict(sorted(sources.items())),
    }


@pytest.mark.parametrize("spec", [SMOKE, PAPER])
def test_the_lazy_plan_is_the_plan_it_replaces(spec):
    plans = plan_dataset(parse_spec(spec))
    assert plan_digest(plans) == PLAN_DIGESTS[spec]  # the same on every machine (support/plans.py)
    eager = list(plans)
    assert plan_summary(plans) == counted_summary(eager)  # the arithmetic summary equals counting
    assert plans[len(plans) - 1] == eager[-1] and plans[-1] == eager[-1]


def test_a_utf8_bom_is_accepted_and_a_latin1_byte_is_named():
    data = SMOKE.read_bytes()
    assert parse_spec_bytes(b"\xef\xbb\xbf" + data, "bom.toml") == parse_spec(SMOKE)
    with pytest.raises(ShaderballError, match=r"bad.toml: not UTF-8 text \(invalid continuation byte at byte 5\)"):
        parse_spec_bytes(b"# caf\xe9\n" + data, "bad.toml")


class Compared(str):
    """A string that counts the comparisons made with it (all instances together)."""

    count = 0

    def __eq__(self, other):
        Compared.count += 1
        return str.__eq__(self, other)

    __hash__ = str.__hash__


def test_the_duplicate_check_of_a_list_field_is_linear():
    """Comparisons counted, not timed: a check by list.count made n^2 (20,000 entries: 10 s;
    200,000: hours), a set and a Counter make about 2n."""
    entries = [Compared("diffuse") for _ in range(20_000)]  # distinct objects: no identity shortcut
    Compared.count = 0
    with pytest.raises(Reject, match=r'\(repeated: "diffuse"\)'):
        StrList(MAP_LAYERS, "map layer names").check(entries)
    assert Compared.count < 4 * len(entries), Compared.count
    text = SMOKE.read_text().replace('layers = ["diffuse"', "layers = [" + '"diffuse", ' * 200_000 + '"diffuse"')
    with pytest.raises(ShaderballError, match=r'\(repeated: "diffuse"\)'):
        parse_spec_bytes(text.encode(), "many.toml")


@pytest.mark.slow
def test_a_spec_from_a_pipe_or_stdin_is_read_once(tmp_path, reference):
    """`<(cat spec.toml)` and /dev/stdin are read once (read twice, the second read gives "[dataset]: missing")."""
    ds = copy_dataset(reference, tmp_path / "ds")
    for how in (f"build <(cat {SMOKE}) --out {ds} --workers 0", f"build /dev/stdin --out {ds} --workers 0 < {SMOKE}"):
        done = run_shell(f"{sys.executable} -m cli {how}")
        assert done.returncode == 0, done.stderr
        assert "already present 16" in done.stdout
    crash.check_complete(ds, reference)


# --------------------------------------------------------------------------- filesystem errors


def _chattr(flag: str, path: Path) -> bool:
    return subprocess.run(["chattr", flag, str(path)], capture_output=True).returncode == 0


@pytest.mark.slow
def test_a_shard_folder_that_cannot_be_written_is_a_message_and_the_build_resumes(tmp_path, reference):
    ds = copy_dataset(reference, tmp_path / "ds")
    shard = ds / "shards" / "s00002"
    for name in ("COMPLETE.json", "m000004_l1.json", "m000004_l1.render.exr"):
        (shard / name).unlink()
    (ds / "manifest.jsonl").unlink()
    if not _chattr("+i", shard):
        pytest.skip("chattr +i does not work here (needs root and a filesystem with attributes)")
    try:
        done = subprocess.run(
            cli("build", SMOKE, "--out", ds, "--workers", 0), cwd=REPO, capture_output=True, text=True, timeout=300
        )
    finally:
        _chattr("-i", shard)
    assert done.returncode == 4, done.stderr
    line = one_error_line(done.stderr)
    assert str(shard) in line and "Operation not permitted (EPERM)" in line and "run the same command again" in line
    again = subprocess.run(
        cli("build", SMOKE, "--out", ds, "--workers", 0), cwd=REPO, capture_output=True, text=True, timeout=300
    )
    assert again.returncode == 0, again.stderr
    crash.check_complete(ds, reference)


@pytest.mark.slow
def test_a_full_disk_is_a_message_and_the_build_resumes(tmp_path, reference):
    """ulimit -f makes every write past 24 KiB fail with EFBIG, as a full disk fails them."""
    ds = copy_dataset(reference, tmp_path / "ds")
    for shard in ("s00001", "s00003"):
        (ds / "shards" / shard / "COMPLETE.json").unlink()
        for path in (ds / "shards" / shard).glob("*_l1.*"):
            path.unlink()
    (ds / "manifest.jsonl").unlink()
    done = run_shell(f"ulimit -f 24; exec {sys.executable} -m cli build {SMOKE} --out {ds} --workers 0")
    assert done.returncode == 4, done.stderr
    line = one_error_line(done.stderr)
    assert "File too large (EFBIG)" in line and str(ds / "shards") in line, line
    assert not list(ds.rglob(".tmp-*")), "a failed write left its temporary file"
    again = subprocess.run(
        cli("build", SMOKE, "--out", ds, "--workers", 0), cwd=REPO, capture_output=True, text=True, timeout=300
    )
    assert again.returncode == 0, again.stderr
    crash.check_complete(ds, reference)


# --------------------------------------------------------------------------- validate --json


def _bless(ds: Path, rel: str) -> None:
    """Make every record agree with the file at ``rel`` as it is now (size and SHA-256), so
    validate decodes it: the file is corrupt, its records are not."""
    data = (ds / rel).read_bytes()
    new = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}

    def fix(record):
        for entry in record.get("files", []):
            if entry.get("path") == rel:
                entry.update(new)
        return record

    manifest = ds / "manifest.jsonl"
    lines = [
        json.dumps(fix(json.loads(line)), sort_keys=True, separators=(",", ":"))
        for line in manifest.read_text().splitlines()
    ]
    manifest.write_text("\n".join(lines) + "\n")
    for marker in ds.glob("shards/*/COMPLETE.json"):
        content = json.loads(marker.read_text())
        content["records"] = [fix(r) for r in content["records"]]
        marker.write_text(json.dumps(content, sort_keys=True, separators=(",", ":")) + "\n")
    for record in ds.glob("shards/*/m*_l*.json"):
        record.write_text(json.dumps(fix(json.loads(record.read_text())), sort_keys=True, separators=(",", ":")))


def _corrupt(data: bytes, how: str) -> bytes:
    b = bytearray(data)
    if how == "flipped byte in the pixel data":
        b[len(b) * 3 // 4] ^= 0xFF
    elif how == "zeroed pixel chunks":
        b[len(b) // 2 :] = bytes(len(b) - len(b) // 2)
    elif how == "truncated":
        b = b[: len(b) // 2]
    elif how == "broken header":
        b[8:200] = b"\xff" * 192
    elif how == "not an EXR":
        b = bytearray(b"GIF89a" + bytes(range(256)) * 20)
    elif how == "empty":
        b = bytearray()
    return bytes(b)


KINDS = ("flipped byte in the pixel data", "zeroed pixel chunks", "truncated", "broken header", "not an EXR", "empty")


def test_validate_json_prints_json_alone_whatever_the_exr_library_prints(tmp_path, reference):
    """OpenEXR prints `Warning: Exception raised reading pixel data ...` on stdout: never before
    the report. Corrupt maps, texture and render files, each corrupt another way, in
    one dataset (their records agree with them, so each one is decoded)."""
    ds = copy_dataset(reference, tmp_path / "ds")
    files = sorted(p.relative_to(ds).as_posix() for p in ds.glob("shards/*/*.exr"))
    spoiled = {}
    for rel, how in zip(files[::3], KINDS):
        (ds / rel).write_bytes(_corrupt((ds / rel).read_bytes(), how))
        _bless(ds, rel)
        spoiled[rel] = how
    done = subprocess.run(cli("validate", ds, "--json"), cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr
    report = json.loads(done.stdout)  # nothing but the JSON on stdout
    named = {
        p["path"]
        for p in report["problems"]
        if p["kind"] in ("undecodable", "bad_layers", "non_finite", "out_of_range", "stats_mismatch")
    }
    assert set(spoiled) <= named, (spoiled, report["problems"])
    assert "Warning" in done.stderr  # what the library said went to stderr, not away


# --------------------------------------------------------------------------- Ctrl-C


def _interrupt(command: list[str], ready, delay_s: float) -> subprocess.CompletedProcess:
    proc = started(command)
    try:
        deadline = time.monotonic() + 240
        while not ready() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.1)
        time.sleep(delay_s)
        os.killpg(proc.pid, signal.SIGINT)  # what a terminal's Ctrl-C does: the whole group
        stdout, stderr = proc.communicate(timeout=240)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return subprocess.CompletedProcess(command, proc.returncode, stdout, stderr)


@contextlib.contextmanager
def busy_processes(n: int):
    """``n`` CPU-bound processes beside the test: a loaded machine."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for proc in procs:
            proc.kill()
            proc.wait()


@pytest.mark.slow
@pytest.mark.parametrize("workers,busy", [(0, 0), (2, 2)], ids=["in-process", "2-workers-2-busy"])
def test_ctrl_c_of_a_build_prints_one_line_and_the_build_resumes(tmp_path, workers, busy):
    """With dask workers on a loaded machine too: no worker or scheduler log reaches stderr."""
    spec = tmp_path / "smoke24.toml"
    spec.write_text(SMOKE.read_text().replace("materials = 8 ", "materials = 24 "))
    out = tmp_path / "ds"

    def rendering():  # every worker is up and has rendered (not one still starting)
        shards = out / "shards"
        return shards.is_dir() and len({p.parent for p in shards.rglob("*.render.exr")}) >= max(1, workers)

    with busy_processes(busy):
        done = _interrupt(cli("build", spec, "--out", out, "--workers", workers), rendering, 1.0)
    assert done.returncode == 130, done.stderr
    assert "Traceback" not in done.stderr + done.stdout, done.stderr
    assert "distributed." not in done.stderr and "ERROR" not in done.stderr, done.stderr
    assert done.stderr.rstrip().splitlines()[-1] == (
        "interrupted (Ctrl-C): every write is atomic, nothing is torn; run the same command again to resume"
    )
    again = subprocess.run(
        cli("build", spec, "--out", out, "--workers", 0), cwd=REPO, capture_output=True, text=True, timeout=400
    )
    assert again.returncode == 0, again.stderr
    checked = subprocess.run(cli("validate", out), cwd=REPO, capture_output=True, text=True, timeout=300)
    assert checked.returncode == 0, checked.stdout
    shutil.rmtree(out)


# Ctrl-C at fixed points of a command's start: while the CLI imports, and while the local dask
# cluster starts (its first worker held with SIGSTOP, so the cluster cannot be up yet, however
# loaded the machine is).

INTERRUPTED = "interrupted (Ctrl-C): every write is atomic, nothing is torn; run the same command again to resume"


def _children(pid: int) -> list[tuple[int, str]]:
    """(pid, command line) of every process whose parent is ``pid`` (from /proc)."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as fh:
                parent = int(fh.read().rsplit(")", 1)[1].split()[1])
            if parent == pid:
                with open(f"/proc/{entry}/cmdline", "rb") as fh:
                    found.append((int(entry), fh.read().replace(b"\0", b" ").decode(errors="replace")))
        except (OSError, ValueError, IndexError):
            continue
    return found


def _finish(proc: subprocess.Popen) -> tuple[str, str]:
    try:
        return proc.communicate(timeout=240)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def _one_interrupted_line(proc: subprocess.Popen, stdout: str, stderr: str) -> None:
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stdout + stderr, stderr
    assert "distributed." not in stderr and "ERROR" not in stderr, stderr
    assert stderr.rstrip().splitlines()[-1] == INTERRUPTED, stderr


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize(
    "command,loaded",
    [("build", "_multiarray_umath"), ("validate --json", "_multiarray_umath"), ("build", "_drjit_ext")],
    ids=["build-cli-imports", "validate-json-cli-imports", "build-mitsuba-loads"],
)
def test_ctrl_c_while_the_cli_or_mitsuba_loads_prints_one_line(tmp_path, reference, command, loaded):
    """The fixed point: a native library is mapped (numpy's: the CLI's first heavy import; drjit's:
    Mitsuba's first, in the build's driver) and the modules after it are not loaded yet."""
    if command == "build":
        args = cli("build", SMOKE, "--out", tmp_path / "ds", "--workers", 0)
    else:
        args = cli("validate", reference, "--json")
    proc = started(args)
    try:
        deadline = time.monotonic() + 120
        while not has_mapped(proc.pid, loaded) and time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.002)
        os.killpg(proc.pid, signal.SIGINT)
    finally:
        stdout, stderr = _finish(proc)
    _one_interrupted_line(proc, stdout, stderr)
    if command != "build":
        doc = json.loads(stdout)  # the one JSON document, and nothing else
        assert doc["exit"] == 130 and doc["ok"] is False and doc["error"] == INTERRUPTED


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_ctrl_c_while_the_local_cluster_starts_stops_the_build_once_it_is_up(tmp_path):
    out = tmp_path / "ds"
    proc = started(cli("build", SMOKE, "--out", out, "--workers", 2))
    held: list[int] = []
    try:
        deadline = time.monotonic() + 240
        while not held and time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()
            held = [pid for pid, command in _children(proc.pid) if "spawn_main" in command]
            for pid in held:
                os.kill(pid, signal.SIGSTOP)
            time.sleep(0.005)
        assert held, "the build spawned no dask worker"
        os.killpg(proc.pid, signal.SIGINT)
        time.sleep(1.0)
        for pid in held:
            os.kill(pid, signal.SIGCONT)
    finally:
        stdout, stderr = _finish(proc)
    _one_interrupted_line(proc, stdout, stderr)
    assert not list(out.rglob("*.render.exr"))  # acted on as the cluster came up, before any shard
