"""A `shaderball publish` killed with SIGKILL is finished by running the same command again:
it recognises what the killed publish left (its lock file, which nobody holds, beside files
publish writes), says so on stderr, clears it and writes the publication anew, which
verifies and is the same bytes as a publication written in one go. A lock file nobody holds
is stale; one a living writer holds is not.

The kill is real: the publish runs in its own session through ``scripts/crash_test.py
--child``, whose hook SIGKILLs the process group inside the N-th atomic write of a kind of
file (as the build's and unpack's crash tests do). Publish's atomic writes, in order:
"other" 1 samples.jsonl (renamed last of the data), 2 and 3 the tar pair, then "spec",
"description" and "manifest" (dataset/), "other" 4 markers.jsonl, 5 preview.png,
6 publication.json, 7 croissant.json, 8 README.md, 9 SHA256SUMS.
"""

from __future__ import annotations

import fcntl
import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.publish.pub_folder import partial_publication
from pipeline.publish.request import PublishRequest
from pipeline.publish.writer import publish
from pipeline.store.layout import LOCK_FILE
from pipeline.store.lock import stale_holder
from support.publishing import files_of

pytestmark = pytest.mark.slow  # the shared smoke build; real processes

REPO = Path(__file__).resolve().parents[1]
CRASH = REPO / "scripts" / "crash_test.py"


@pytest.fixture(scope="module")
def whole(reference, tmp_path_factory) -> dict[str, bytes]:
    """The publication of the smoke dataset written in one go: every file's bytes."""
    out = tmp_path_factory.mktemp("whole") / "pub"
    publish(PublishRequest(str(reference), str(out)))
    return files_of(out)


def killed_publish(source: Path, out: Path, hook: str) -> int:
    """Run `shaderball publish SOURCE --out OUT` in a new session, killed by ``hook``; the
    killed process's pid, as its lock file names it."""
    command = [sys.executable, str(CRASH), "--child", "--hook", hook, "--", "publish", str(source), "--out", str(out)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=300, start_new_session=True, cwd=REPO)
    assert done.returncode == -signal.SIGKILL, (hook, done.returncode, done.stderr[-2000:])
    holder = json.loads((out / LOCK_FILE).read_text())
    assert holder["purpose"] == "publish"
    return holder["pid"]


def shaderball(*args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "cli", *map(str, args)], capture_output=True, text=True, timeout=300, cwd=REPO
    )


#: (hook, what the killed publish left besides its lock file)
KILL_POINTS = [
    ("other:2:write", "temporary files only: a torn first tar"),
    ("manifest:1:renamed", "the tars and dataset/ files, samples.jsonl still temporary"),
    ("other:8:renamed", "everything but SHA256SUMS"),
    ("other:9:renamed", "a whole publication: killed before it let the folder go"),
]


@pytest.mark.parametrize("hook, what", KILL_POINTS, ids=[k[0] for k in KILL_POINTS])
def test_the_same_command_replaces_a_killed_publish(reference, whole, tmp_path, hook, what):
    pub = tmp_path / "pub"
    pid = killed_publish(reference, pub, hook)
    assert (pub / LOCK_FILE).exists(), what
    assert partial_publication(str(pub))["pid"] == pid
    done = shaderball("publish", reference, "--out", pub)
    assert done.returncode == 0, done.stderr[-3000:]
    assert f"{pub}: found a partial publication (killed publish, pid {pid} " in done.stderr, done.stderr
    assert "replacing it" in done.stderr
    verified = shaderball("verify", pub)
    assert verified.returncode == 0, verified.stderr[-3000:]
    assert not (pub / LOCK_FILE).exists()
    assert files_of(pub) == whole  # byte for byte; no temporary file of the killed one left


def test_a_killed_publish_beside_other_files_is_refused_and_kept(reference, tmp_path):
    pub = tmp_path / "pub"
    killed_publish(reference, pub, "manifest:1:renamed")
    (pub / "notes.txt").write_text("mine")
    before = files_of(pub)
    assert partial_publication(str(pub)) is None
    done = shaderball("publish", reference, "--out", pub)
    assert done.returncode == 2 and "a new or empty folder" in done.stderr, done.stderr
    assert files_of(pub) == before


HOLD = r"""
import fcntl, os, sys
fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT)
os.write(fd, b'{"purpose": "publish", "pid": %d}' % os.getpid())
fcntl.flock(fd, fcntl.LOCK_EX)
print("held", flush=True)
sys.stdin.read()  # held until the test kills it (or ends: its stdin closes), however long that takes
"""


def test_a_lock_is_stale_once_its_holder_is_gone(reference, whole, tmp_path):
    """A lock file a living process holds is not stale, whatever its content says: a publish
    into its folder is refused as busy (exit code 3) naming the holder. Once the process is
    killed (SIGKILL: no clean-up) the lock is stale, and the same publish takes it over."""
    pub = tmp_path / "pub"
    pub.mkdir()
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(pub / LOCK_FILE)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        assert stale_holder(str(pub)) is None and partial_publication(str(pub)) is None
        busy = shaderball("publish", reference, "--out", pub)
        assert busy.returncode == 3 and f"pid {holder.pid}" in busy.stderr, busy.stderr
    finally:
        holder.kill()
        holder.wait(timeout=60)
        holder.stdin.close()
    assert stale_holder(str(pub)) == {"purpose": "publish", "pid": holder.pid}
    with open(pub / LOCK_FILE, "rb") as fh:  # nobody holds it: anyone may lock it now
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    assert stale_holder(str(tmp_path / "missing")) is None
    done = shaderball("publish", reference, "--out", pub)
    assert done.returncode == 0 and f"(killed publish, pid {holder.pid} " in done.stderr, done.stderr
    assert files_of(pub) == whole
