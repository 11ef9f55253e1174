"""One writer per dataset folder (pipeline.store.lock): a second writer is refused
naming the holder, readers run beside a writer, and a writer killed with kill -9 never
blocks the next one. Every case runs real processes."""

from __future__ import annotations

import fcntl
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipeline.errors import FolderBusy
from pipeline.publish import unpack as unpack_module
from pipeline.publish.request import PublishRequest, UnpackRequest
from pipeline.store.atomic import TEMP_PREFIX
from pipeline.store.layout import LOCK_FILE
from pipeline.store.lock import holder_text, holds_lock, writer_lock
from support.processes import cli, started

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"
HOLD = (
    "import sys, time\n"
    "from pipeline.store.lock import writer_lock\n"
    "with writer_lock(sys.argv[1], sys.argv[2]):\n"
    "    print('held', flush=True)\n"
    "    time.sleep(600)\n"
)


def run(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(cli(*args), cwd=REPO, capture_output=True, text=True, timeout=timeout)


def hold(folder: Path, purpose: str = "build") -> subprocess.Popen:
    """A process that holds ``folder``'s lock until it is killed."""
    proc = started([sys.executable, "-c", HOLD, str(folder), purpose])
    assert proc.stdout.readline().strip() == "held", proc.stderr.read()
    return proc


def kill9(proc: subprocess.Popen) -> None:
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)


def wait_for_lock(folder: Path, proc: subprocess.Popen, timeout_s: float = 120) -> dict:
    """The holder's description, once a writer (``proc``) has taken ``folder``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        try:
            text = (folder / LOCK_FILE).read_text()
            if text.strip():
                return json.loads(text)
        except (FileNotFoundError, ValueError):
            pass
        time.sleep(0.05)
    raise AssertionError(f"{folder}: no writer took the lock within {timeout_s} s")


def snapshot(folder: Path) -> dict:
    return {
        p.relative_to(folder).as_posix(): (p.stat().st_size, p.stat().st_mtime_ns)
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _transient(rel: str) -> bool:
    name = Path(rel).name
    return name.startswith(TEMP_PREFIX) or rel == LOCK_FILE


def test_a_second_writer_is_refused_naming_the_holder(tmp_path):
    folder = tmp_path / "ds"
    folder.mkdir()
    holder = hold(folder, "build")
    try:
        with pytest.raises(FolderBusy) as refused:
            with writer_lock(str(folder), "validate --repair"):
                pass
        message = str(refused.value)
        assert f"pid {holder.pid} on host " in message and "build" in message and "since 20" in message
        assert "-c" in message  # the holder's command line
        assert refused.value.exit_code == 3
    finally:
        kill9(holder)


def test_a_hostile_holder_is_shown_on_one_printable_line():
    """Anyone may write the lock file: its fields never put a newline or an escape in a message."""
    text = holder_text(
        {"purpose": "build\nerror: forged", "pid": [1, 2], "host": "h\x1b[2J", "since": "x" * 5000, "command": "a\rb"}
    )
    assert text.isprintable() and len(text) < 1000, text
    assert "build\\nerror: forged" in text and "h\\x1b[2J" in text and "pid [1, 2]" in text


def test_a_writer_killed_with_kill_9_never_blocks_the_next(tmp_path, monkeypatch):
    """Never blocks, by construction: one non-blocking lock attempt takes the lock the dead writer
    left (counted, not timed)."""
    folder = tmp_path / "ds"
    folder.mkdir()
    kill9(hold(folder))
    assert (folder / LOCK_FILE).exists()  # left behind, but nobody holds it
    calls, flock = [], fcntl.flock

    def counted(fd, operation):
        calls.append(operation)
        return flock(fd, operation)

    monkeypatch.setattr(fcntl, "flock", counted)
    with writer_lock(str(folder), "build"):
        assert calls == [fcntl.LOCK_EX | fcntl.LOCK_NB], calls
        assert holds_lock(str(folder))
        assert json.loads((folder / LOCK_FILE).read_text())["pid"] == os.getpid()
    assert not (folder / LOCK_FILE).exists()  # its holder removes it on the way out
    assert not holds_lock(str(folder))


def test_the_lock_is_counted_per_process_so_repair_may_resume_its_build(tmp_path):
    folder = tmp_path / "ds"
    folder.mkdir()
    with writer_lock(str(folder), "validate --repair"):
        with writer_lock(str(folder), "build"):
            pass
        assert holds_lock(str(folder)) and (folder / LOCK_FILE).exists()
        other = subprocess.run(
            [sys.executable, "-c", HOLD, str(folder), "build"], cwd=REPO, capture_output=True, text=True, timeout=60
        )
        assert other.returncode != 0 and "FolderBusy" in other.stderr and "validate --repair" in other.stderr
    assert not holds_lock(str(folder))


def test_a_lock_file_that_is_a_symlink_or_a_fifo_is_refused_not_followed(tmp_path):
    outside = tmp_path / "outside.txt"
    outside.write_text("keep")
    linked, fifo = tmp_path / "linked", tmp_path / "fifo"
    linked.mkdir()
    fifo.mkdir()
    (linked / LOCK_FILE).symlink_to(outside)
    os.mkfifo(fifo / LOCK_FILE)
    for folder, what in ((linked, "symbolic link"), (fifo, "not a regular file")):
        with pytest.raises(Exception, match=what):
            with writer_lock(str(folder), "build"):
                pass
    assert outside.read_text() == "keep"


def test_unpack_is_refused_when_a_writer_took_the_folder_after_its_check(tmp_path, monkeypatch):
    """The race the lock closes: DIR was new when unpack looked, a build took it before the
    first write. unpack is refused (exit code 3) and writes nothing there."""
    out = tmp_path / "ds"
    (tmp_path / "pub").mkdir()  # the request names an existing folder; its reading is stubbed
    holders = []
    real_output = unpack_module.Output

    def output_then_a_build_starts(path, **options):
        made = real_output(path, **options)
        holders.append(hold(Path(path), "build"))
        return made

    monkeypatch.setattr(unpack_module, "open_publication", lambda pub, limits: object())
    monkeypatch.setattr(unpack_module, "verify_publication", lambda publication, progress: None)
    monkeypatch.setattr(unpack_module, "Output", output_then_a_build_starts)
    try:
        with pytest.raises(FolderBusy, match="build, pid"):
            unpack_module.unpack(UnpackRequest(str(tmp_path / "pub"), str(out)))
        assert os.listdir(out) == [LOCK_FILE]  # the build's lock; unpack wrote nothing
    finally:
        for proc in holders:
            kill9(proc)


def _spec_with_seed(tmp_path: Path, seed: int) -> Path:
    path = tmp_path / f"seed{seed}.toml"
    path.write_text(SMOKE.read_text().replace("seed = 20191117", f"seed = {seed}"))
    return path


@pytest.mark.slow
def test_two_builds_of_different_specs_on_one_new_folder_one_is_refused(tmp_path, reference):
    """Without the lock both builds would see a new folder and mix two datasets."""
    from conftest import crash_module

    out = tmp_path / "mix"
    other = _spec_with_seed(tmp_path, 7)
    procs = [started(cli("build", spec, "--out", out, "--workers", 0)) for spec in (SMOKE, other)]
    outputs = [p.communicate(timeout=400) for p in procs]
    codes = [p.returncode for p in procs]
    assert sorted(codes)[0] == 0 and sorted(codes)[1] in (2, 3), (codes, outputs)
    loser = outputs[codes.index(sorted(codes)[1])][1]
    assert "Traceback" not in loser and loser.startswith("error: "), loser
    assert ("being written by another writer: build, pid" in loser) or ("different spec" in loser), loser
    winner = (SMOKE, other)[codes.index(0)]
    assert (out / "spec.toml").read_text().count(f"seed = {7 if winner == other else 20191117}") == 1
    assert run("validate", out).returncode == 0
    if winner == SMOKE:
        crash_module().check_complete(out, reference)


@pytest.mark.slow
def test_repair_and_a_second_build_during_a_build_are_refused_and_readers_run_beside_it(tmp_path):
    """Without the lock repair would delete a live build's files; deterministically:
    the writers start once the build holds the folder."""
    out = tmp_path / "ds"
    build = started(cli("build", SMOKE, "--out", out, "--workers", 0))
    try:
        holder = wait_for_lock(out, build)
        assert holder["purpose"] == "build" and holder["pid"] == build.pid
        before = snapshot(out)
        repair = run("validate", out, "--repair")
        assert repair.returncode == 3, repair
        assert repair.stderr.startswith(
            f"error: DIR: {json.dumps(str(out))} is being written by another writer: build, pid {build.pid} on host "
        ), repair.stderr
        assert "Traceback" not in repair.stderr
        other = run("build", _spec_with_seed(tmp_path, 7), "--out", out, "--workers", 0)
        assert other.returncode in (2, 3) and "Traceback" not in other.stderr, other
        # Readers beside the writer: no traceback, nothing written by them.
        checked = run("validate", out, "--json")
        assert checked.returncode in (0, 1) and "Traceback" not in checked.stderr, checked
        assert json.loads(checked.stdout)["expected"] == 16
        info = run("info", out)
        assert info.returncode == 0 and "Traceback" not in info.stderr, info
        # A temp file (in any folder) is renamed by its writer, and the lock file goes when the
        # build ends: on a loaded machine the build may finish meanwhile. Anything else lost
        # was taken by the refused writers or the readers.
        files_now = snapshot(out)
        lost = [rel for rel in before if rel not in files_now and not _transient(rel)]
        assert not lost, f"a writer lost files: {lost}"
        stdout, stderr = build.communicate(timeout=400)
    finally:
        if build.poll() is None:
            kill9(build)
    assert build.returncode == 0, stderr
    assert run("validate", out).returncode == 0
    assert not (out / LOCK_FILE).exists()


@pytest.mark.slow
def test_a_build_killed_with_kill_9_does_not_block_its_resume(tmp_path, reference):
    from conftest import crash_module

    out = tmp_path / "ds"
    build = started(cli("build", SMOKE, "--out", out, "--workers", 0))
    wait_for_lock(out, build)
    kill9(build)
    resumed = run("build", SMOKE, "--out", out, "--workers", 0)
    assert resumed.returncode == 0, resumed.stderr
    assert not (out / LOCK_FILE).exists()
    crash_module().check_complete(out, reference)


# --------------------------------------------------------------------------- publish --out PUB


def _busy_line(folder: Path, purpose: str, pid: int) -> str:
    return f"error: PUB: {json.dumps(str(folder))} is being written by another writer: {purpose}, pid {pid} on host "


@pytest.mark.slow
def test_publish_into_a_folder_another_writer_holds_is_refused_naming_it(tmp_path, reference):
    pub = tmp_path / "pub"
    pub.mkdir()
    holder = hold(pub, "publish")
    try:
        refused = run("publish", reference, "--out", pub)
        assert refused.returncode == 3, refused
        assert refused.stderr.startswith(_busy_line(pub, "publish", holder.pid)), refused.stderr
        assert "Traceback" not in refused.stderr
        assert os.listdir(pub) == [LOCK_FILE]  # the holder's; publish wrote nothing
    finally:
        kill9(holder)


@pytest.mark.slow
def test_publish_is_refused_when_a_writer_took_the_folder_after_its_check(tmp_path, reference, monkeypatch):
    """The race the lock closes: PUB was new when publish looked, another publish took it
    before the first write. This one is refused (exit code 3) and writes nothing there."""
    from pipeline.publish import pub_folder, writer

    pub = tmp_path / "pub"
    holders = []
    real_check = pub_folder.check_out

    def checked_then_another_publish_starts(out, source=None, label="DIR", **kwargs):
        real_check(out, source, label, **kwargs)
        os.makedirs(out)
        holders.append(hold(Path(out), "publish"))

    monkeypatch.setattr(pub_folder, "check_out", checked_then_another_publish_starts)
    try:
        with pytest.raises(FolderBusy) as refused:
            writer.publish(PublishRequest(str(reference), str(pub)))
        assert str(refused.value).startswith(_busy_line(pub, "publish", holders[0].pid)[len("error: ") :])
        assert refused.value.exit_code == 3
        assert os.listdir(pub) == [LOCK_FILE]  # the other publish's lock; nothing of this one
    finally:
        for proc in holders:
            kill9(proc)


@pytest.mark.slow
def test_a_second_publish_while_the_first_holds_the_folder_is_refused_and_the_first_verifies(tmp_path, reference):
    """Two real publish processes: the second starts once the first holds PUB, and the first
    is stopped (SIGSTOP) meanwhile, so it cannot finish before the second looks."""
    pub = tmp_path / "pub"
    first = started(cli("publish", reference, "--out", pub))
    try:
        holder = wait_for_lock(pub, first)
        assert holder["purpose"] == "publish" and holder["pid"] == first.pid
        os.kill(first.pid, signal.SIGSTOP)
        try:
            second = run("publish", reference, "--out", pub)
        finally:
            os.kill(first.pid, signal.SIGCONT)
        assert second.returncode == 3, second
        assert second.stderr.startswith(_busy_line(pub, "publish", first.pid)), second.stderr
        assert "Traceback" not in second.stderr
        stdout, stderr = first.communicate(timeout=400)
    finally:
        if first.poll() is None:
            kill9(first)
    assert first.returncode == 0, stderr
    assert not (pub / LOCK_FILE).exists()
    verified = run("verify", pub)
    assert verified.returncode == 0, verified.stdout + verified.stderr
    unpacked = run("unpack", pub, "--out", tmp_path / "back")
    assert unpacked.returncode == 0, unpacked.stderr
    assert (tmp_path / "back" / "manifest.jsonl").read_bytes() == (reference / "manifest.jsonl").read_bytes()


@pytest.mark.slow
def test_two_publishes_started_together_into_one_folder_exactly_one_succeeds(tmp_path, reference):
    pub = tmp_path / "pub"
    procs = [started(cli("publish", reference, "--out", pub)) for _ in range(2)]
    outputs = [p.communicate(timeout=400) for p in procs]
    codes = [p.returncode for p in procs]
    assert sorted(codes)[0] == 0 and sorted(codes)[1] in (2, 3), (codes, outputs)
    loser = outputs[codes.index(sorted(codes)[1])][1]
    assert loser.startswith("error: ") and "Traceback" not in loser, loser
    assert str(pub) in loser  # the folder is named, busy or already filled
    verified = run("verify", pub)
    assert verified.returncode == 0, verified.stdout + verified.stderr
