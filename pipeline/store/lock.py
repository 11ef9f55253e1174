"""One writer per dataset folder at a time: an exclusive ``flock`` on ``DIR/.shaderball.lock``.

Writers (a build, ``validate --repair``, ``shaderball unpack`` into its DIR, ``shaderball
publish`` into its PUB) hold the lock for as long as they write; a second writer is refused at
once (:class:`pipeline.errors.FolderBusy`, exit code 3) with a message naming the holder
(host, pid, command, since). Readers (validate without ``--repair``, info, preview, publish of
the dataset it reads, the training loader) never take it: every file is written atomically, so
they see whole files, old or new, beside a writer.

Why ``flock``: the kernel drops the lock when its holder dies, however it dies (``kill -9``
included), so a killed writer never blocks the next one; there is nothing stale to clean up
by hand. The holder's description written into the file is information only, never trusted
as the lock itself.

The lock file is unlinked by its holder before it lets go, so a finished dataset holds no
lock file; a writer killed with ``kill -9`` leaves one behind, unlocked, which the next
writer takes over and removes. A writer that opened the file just before it was unlinked
finds the path gone or pointing to another file after it locks, and tries again.

A process that holds the lock may take it again (a repair resumes the build inside itself):
the lock is counted per folder per process.

Shared filesystems (a cluster build): the build's driver takes the lock and holds it for the
whole build; its dask workers write shards under it and take no lock. On Linux NFS clients
``flock`` is carried out as a POSIX lock on the whole file, which the NFS server arbitrates
(NFSv4, or NFSv3 with lockd/statd): a second driver on another node is refused as it would
be locally. A driver on a node that crashes holds the lock until the server notices (the
NFSv4 lease, typically 90 s; NFSv3 waits for the node's statd to report its reboot). A
mount with ``nolock`` or ``local_lock=flock`` keeps locks on each node: then two drivers on
two nodes are NOT kept apart. A filesystem that refuses locks altogether (e.g. Lustre
mounted without ``flock``) makes every writer stop with a message saying so.
"""

from __future__ import annotations

import contextlib
import datetime
import errno
import fcntl
import json
import os
import shlex
import socket
import stat
import sys

from pipeline.errors import FilesystemError, FolderBusy, ShaderballError, quoted
from pipeline.store.layout import LOCK_FILE

#: Bytes of the holder's description read back (it is one short JSON line).
HOLDER_BYTES = 4096
#: Attempts at locking a file that another writer unlinks meanwhile before giving up.
ATTEMPTS = 50

_held: dict[str, list] = {}  # real path of the folder -> [fd, depth]


def lock_path(root: str) -> str:
    return os.path.join(root, LOCK_FILE)


def holder_text(info: dict | None) -> str:
    """The holder as people read it: 'build, pid 4242 on host node1, since ... (`command`)'."""
    if not isinstance(info, dict) or not info:
        return "a writer that is just starting (it has not yet said who it is)"
    command = info.get("command")
    purpose, pid, host, since = (_shown(info.get(key, "?")) for key in ("purpose", "pid", "host", "since"))
    return f"{purpose}, pid {pid} on host {host}, since {since}" + (f" (`{_shown(command)}`)" if command else "")


def _shown(value, limit: int = 200) -> str:
    """A holder's field as one printable line: the lock file is anyone's to write, so a
    newline or a terminal escape in it is shown escaped, and a long value cut."""
    text = value if isinstance(value, str) else json.dumps(value)
    text = "".join(ch if ch.isprintable() else ascii(ch)[1:-1] for ch in text)
    return text if len(text) <= limit else text[:limit] + "..."


def _read_holder(fd: int) -> dict | None:
    try:
        data = os.pread(fd, HOLDER_BYTES, 0)
        info = json.loads(data.decode("utf-8")) if data.strip() else None
    except (OSError, ValueError):
        return None
    return info if isinstance(info, dict) else None


def busy(root: str, holder: dict | None, label: str = "DIR") -> FolderBusy:
    """The refusal of a writer that finds ``root`` held by ``holder``; ``label`` names the
    folder as its command calls it (DIR, PUB)."""
    return FolderBusy(
        f"{label}: {quoted(root)} is being written by another writer: {holder_text(holder)}. "
        "One writer at a time (build, validate --repair, unpack, publish --out): wait for it to "
        "finish, or stop it (a writer that is killed releases the folder at once); "
        "readers (validate, info, preview, publish of a dataset, train) may run beside it"
    )


def current_holder(root: str) -> dict | None:
    """Who holds ``root`` now (their description, ``{}`` when not yet written), or None when
    nobody does. The probe creates and removes nothing: it takes a shared lock on the lock
    file as it is, which a writer's exclusive lock refuses, and lets it go at once (a writer
    starting in that instant is refused as busy; only a folder already refused asks)."""
    probe = _probe(root)
    return probe[1] if probe is not None and probe[0] else None


def stale_holder(root: str) -> dict | None:
    """The description a writer that is gone left in ``root``'s lock file (``{}`` when it
    wrote none), or None when there is no lock file or a writer holds it now. A lock file
    nobody holds is stale: its holder was killed (a living holder keeps its ``flock``, and
    unlinks the file before it lets go), whatever process now has its pid. Like
    :func:`current_holder`, the probe creates and removes nothing."""
    probe = _probe(root)
    return probe[1] if probe is not None and not probe[0] else None


def _probe(root: str) -> tuple[bool, dict] | None:
    """(whether a writer holds ``root``'s lock file now, the description in it: ``{}`` when
    none), or None when there is no lock file or locks cannot be told here. A shared lock is
    tried on the file as it is (a writer's exclusive lock refuses it) and let go at once."""
    try:
        fd = os.open(lock_path(root), os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return True, _read_holder(fd) or {}
        except OSError:
            return None
        return False, _read_holder(fd) or {}  # closing the file lets the shared lock go
    finally:
        os.close(fd)


def _open_lock_file(root: str) -> int:
    path = lock_path(root)
    flags = os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC
    try:
        fd = os.open(path, flags, 0o666)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise ShaderballError(
                f"{quoted(path)} is a symbolic link; a dataset folder holds none "
                "(`shaderball validate` reports it); remove it"
            ) from None
        raise FilesystemError(f"cannot create the writer lock {quoted(path)}: {exc.strerror}") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise ShaderballError(f"{quoted(path)} is not a regular file; remove it (it is the writer lock)")
    return fd


def _same_file(fd: int, path: str) -> bool:
    try:
        here, there = os.fstat(fd), os.lstat(path)
    except FileNotFoundError:
        return False
    return (here.st_dev, here.st_ino) == (there.st_dev, there.st_ino)


def _acquire(root: str, purpose: str, label: str) -> int:
    path = lock_path(root)
    for _ in range(ATTEMPTS):
        fd = _open_lock_file(root)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_holder(fd)
            os.close(fd)
            raise busy(root, holder, label) from None
        except OSError as exc:
            os.close(fd)
            raise FilesystemError(
                f"the filesystem of {quoted(root)} refuses file locks ({exc.strerror}), so two writers "
                "could not be kept apart; use a filesystem (or mount option) with flock support"
            ) from None
        if _same_file(fd, path):
            break
        os.close(fd)  # its holder unlinked it as we locked it: take the new one
    else:
        raise FolderBusy(f"{quoted(root)}: the writer lock {quoted(path)} kept changing hands; try again")
    info = {
        "purpose": purpose,
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "since": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "command": shlex.join(sys.argv),
    }
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(info, sort_keys=True) + "\n").encode("utf-8"), 0)
    except OSError:
        pass  # a full disk: the lock holds all the same, only the description is lost
    return fd


def _release(root: str, fd: int) -> None:
    with contextlib.suppress(OSError):
        if _same_file(fd, lock_path(root)):
            os.unlink(lock_path(root))  # while still locked: see the module's docstring
    os.close(fd)


@contextlib.contextmanager
def writer_lock(root: str, purpose: str, label: str = "DIR"):
    """Hold the folder ``root`` (an existing directory) for writing; ``purpose`` names the
    writer in a refusal ("build", "validate --repair", "unpack", "publish"), ``label`` the
    folder in this writer's own refusal (DIR; PUB for publish)."""
    key = os.path.realpath(root)
    if key in _held:
        _held[key][1] += 1
        try:
            yield
        finally:
            _held[key][1] -= 1
        return
    fd = _acquire(root, purpose, label)
    _held[key] = [fd, 1]
    try:
        yield
    finally:
        del _held[key]
        _release(root, fd)


def holds_lock(root: str) -> bool:
    """This process holds ``root`` (a writer's own code may rely on it)."""
    return os.path.realpath(root) in _held
