"""A real SLURM for the tests: munged, slurmctld and one slurmd per node, started as root from
Debian's packages (`slurm-wlm`, `munge`) in a temporary state folder, and stopped again.

Nothing of the machine's own configuration is read or changed: the daemons get their own
munge key, socket, ports, spool and log files, and client commands find this cluster through
``SLURM_CONF`` in :attr:`LocalSlurm.env`. :meth:`LocalSlurm.stop` kills only the processes it
started (by pid, then their pid files' pids), never by name.

One machine is simulated as ``nodes`` SLURM nodes: every ``NodeName`` points at this host
with its own slurmd port (``slurmd -N NAME``, which Debian's build accepts), each node with
all the machine's CPUs. ``ProctrackType=proctrack/linuxproc`` and ``TaskPlugin=task/none``:
no cgroups (they are not available in every container).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import secrets
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

DAEMONS = ("munged", "slurmctld", "slurmd")
CLIENTS = ("sbatch", "squeue", "scontrol", "scancel", "sinfo")
SBIN = "/usr/sbin:/sbin"


def which(name: str) -> str | None:
    return shutil.which(name, path=os.environ.get("PATH", "") + os.pathsep + SBIN)


def unavailable_reason() -> str | None:
    """Why no real SLURM can run here, or None when it can."""
    if os.environ.get("SHADERBALL_NO_SLURM"):
        return "real SLURM tests turned off: SHADERBALL_NO_SLURM is set"
    missing = [name for name in DAEMONS + CLIENTS if which(name) is None]
    if missing:
        return (
            f"real SLURM not available: {', '.join(missing)} not found (`make slurm`, part of `make test`, "
            "installs Debian's slurm-wlm and munge as root with apt-get)"
        )
    if os.geteuid() != 0:
        return "real SLURM not available: starting slurmd needs root"
    return None


def die_with_parent() -> None:
    """preexec_fn: SIGTERM this child when the process that started it dies (even by SIGKILL),
    so a killed test run leaves no daemon behind. Linux only; elsewhere nothing."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@dataclass
class LocalSlurm:
    nodes: int = 1
    #: per node; RealMemory is what --mem asks are checked against.
    cpus: int = field(default_factory=lambda: os.cpu_count() or 1)
    memory_mb: int = 8000
    #: per node: a ``gpu`` GRES of this many devices, declared in gres.conf with no hardware
    #: behind it (each a plain file), so jobs can ask for ``--gres=gpu:N``.
    gpus: int = 2
    partition: str = "debug"
    root: Path | None = None
    procs: list = field(default_factory=list)

    @property
    def node_names(self) -> list[str]:
        return [f"sb{i + 1}" for i in range(self.nodes)]

    @property
    def env(self) -> dict:
        """The environment for client commands (sbatch, squeue, ...) and builds."""
        return dict(
            os.environ, SLURM_CONF=str(self.root / "slurm.conf"), PATH=os.environ.get("PATH", "") + os.pathsep + SBIN
        )

    # ------------------------------------------------------------------ start and stop

    def start(self, timeout_s: float = 60.0) -> LocalSlurm:
        # A short path: munge's socket path must fit a sockaddr_un (108 bytes).
        self.root = Path(tempfile.mkdtemp(prefix="sb-slurm-"))
        for sub in ["state", "log", "munge"] + [f"spool/{name}" for name in self.node_names]:
            (self.root / sub).mkdir(parents=True)
        os.chmod(self.root / "munge", 0o700)
        key = self.root / "munge" / "munge.key"
        key.write_bytes(secrets.token_bytes(128))
        os.chmod(key, 0o400)
        (self.root / "slurm.conf").write_text(self.config())
        (self.root / "gres.conf").write_text(self.gres_config())
        try:
            self._daemon(
                [
                    which("munged"),
                    "--foreground",
                    "--force",
                    f"--key-file={key}",
                    f"--socket={self.munge_socket}",
                    f"--pid-file={self.root / 'munge' / 'munged.pid'}",
                    f"--log-file={self.root / 'log' / 'munged.log'}",
                    f"--seed-file={self.root / 'munge' / 'munged.seed'}",
                ],
                "munged",
            )
            self._wait(lambda: self.munge_socket.exists(), timeout_s, "munged made no socket")
            self._daemon([which("slurmctld"), "-D", "-i", "-f", str(self.root / "slurm.conf")], "slurmctld")
            self._wait(
                lambda: self.scontrol("ping", check=False).returncode == 0, timeout_s, "slurmctld does not answer"
            )
            for name in self.node_names:
                self._daemon([which("slurmd"), "-D", "-N", name, "-f", str(self.root / "slurm.conf")], f"slurmd-{name}")
            self._wait(self._nodes_idle, timeout_s, "nodes did not come up idle")
        except BaseException:
            self.stop()
            raise
        return self

    def stop(self) -> None:
        """Cancel this cluster's jobs, stop its daemons, then kill what is left of ours.

        Job processes outlive slurmd (slurmstepd is re-parented to init): every process whose
        environment names this cluster's ``SLURM_CONF`` (daemons, job steps, the jobs'
        workers) was started through this cluster and is killed by pid; nothing else is.
        """
        if self.procs and all(p.poll() is None for p in self.procs):
            with contextlib.suppress(Exception):
                self.run("scancel", "--user", str(os.getuid()), check=False, timeout_s=10)
                deadline = time.monotonic() + 15
                while self.queue() and time.monotonic() < deadline:
                    time.sleep(0.3)
        for proc in reversed(self.procs):
            with contextlib.suppress(ProcessLookupError):
                proc.terminate()
        deadline = time.monotonic() + 10
        for proc in reversed(self.procs):
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            if proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    proc.kill()
                proc.wait(timeout=10)
        self.procs.clear()
        for _ in range(3):
            left = self.processes()
            for pid in left:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
            if not left:
                break
            time.sleep(0.3)

    def processes(self) -> list[int]:
        """Live processes (not this one) whose environment holds this cluster's SLURM_CONF."""
        if self.root is None:
            return []
        marker = f"SLURM_CONF={self.root / 'slurm.conf'}".encode()
        pids = []
        for entry in os.listdir("/proc"):
            if not entry.isdigit() or int(entry) == os.getpid():
                continue
            try:
                environ = Path(f"/proc/{entry}/environ").read_bytes().split(b"\0")
                state = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()[0]
            except (OSError, IndexError):
                continue
            if marker in environ and state != "Z":
                pids.append(int(entry))
        return pids

    def cleanup(self) -> None:
        if self.root is not None:
            shutil.rmtree(self.root, ignore_errors=True)

    # ------------------------------------------------------------------ config

    @property
    def munge_socket(self) -> Path:
        return self.root / "munge" / "munge.socket"

    def config(self) -> str:
        host = socket.gethostname()
        r = self.root
        lines = [
            "ClusterName=shaderballtest",
            f"SlurmctldHost={host}",
            f"SlurmctldPort={free_port()}",
            "SlurmUser=root",
            "SlurmdUser=root",
            "AuthType=auth/munge",
            "CredType=cred/munge",
            f"AuthInfo=socket={self.munge_socket}",
            f"StateSaveLocation={r / 'state'}",
            f"SlurmdSpoolDir={r / 'spool'}/%n",
            f"SlurmctldPidFile={r / 'slurmctld.pid'}",
            f"SlurmdPidFile={r / 'spool'}/slurmd-%n.pid",
            f"SlurmctldLogFile={r / 'log' / 'slurmctld.log'}",
            f"SlurmdLogFile={r / 'log'}/slurmd-%n.log",
            "ProctrackType=proctrack/linuxproc",
            "TaskPlugin=task/none",
            "JobAcctGatherType=jobacct_gather/none",
            "AccountingStorageType=accounting_storage/none",
            "JobCompType=jobcomp/none",
            "SwitchType=switch/none",
            "MpiDefault=none",
            "MailProg=/bin/true",
            "SelectType=select/cons_tres",
            "SelectTypeParameters=CR_Core_Memory",
            "SchedulerType=sched/backfill",
            "ReturnToService=2",
            # Keep finished jobs visible to `scontrol show job` for the whole test.
            "MinJobAge=3600",
            "KillWait=5",
            "SlurmdTimeout=60",
            "InactiveLimit=0",
            "SlurmctldDebug=info",
            "SlurmdDebug=info",
            "GresTypes=gpu",
        ]
        for name in self.node_names:
            lines.append(
                f"NodeName={name} NodeHostname={host} NodeAddr=127.0.0.1 Port={free_port()} "
                f"CPUs={self.cpus} RealMemory={self.memory_mb} Gres=gpu:{self.gpus} State=UNKNOWN"
            )
        lines.append(
            f"PartitionName={self.partition} Nodes={','.join(self.node_names)} Default=YES MaxTime=INFINITE State=UP"
        )
        return "\n".join(lines) + "\n"

    def gres_config(self) -> str:
        """gres.conf (read from slurm.conf's folder): each node's GPUs, plain files standing in
        for /dev/nvidiaN, so slurmd hands a job its devices' indices in CUDA_VISIBLE_DEVICES."""
        lines = []
        for name in self.node_names:
            for i in range(self.gpus):
                device = self.root / "dev" / f"{name}-gpu{i}"
                device.parent.mkdir(exist_ok=True)
                device.touch()
                lines.append(f"NodeName={name} Name=gpu File={device}")
        return "\n".join(lines) + "\n"

    # ------------------------------------------------------------------ commands

    def run(self, *argv: str, check: bool = True, timeout_s: float = 30.0) -> subprocess.CompletedProcess:
        result = subprocess.run(
            [which(argv[0]) or argv[0], *argv[1:]], env=self.env, capture_output=True, text=True, timeout=timeout_s
        )
        if check and result.returncode != 0:
            raise AssertionError(f"`{' '.join(argv)}` exited {result.returncode}:\n{result.stdout}{result.stderr}")
        return result

    def scontrol(self, *args: str, check: bool = True) -> subprocess.CompletedProcess:
        return self.run("scontrol", *args, check=check)

    def jobs(self) -> dict[str, dict]:
        """Every job slurmctld knows (finished ones too, for MinJobAge): id -> its fields."""
        out = self.scontrol("show", "job", "--oneliner").stdout
        jobs = {}
        for line in out.splitlines():
            fields = dict(item.split("=", 1) for item in line.split() if "=" in item)
            if "JobId" in fields:
                jobs[fields["JobId"]] = fields
        return jobs

    def queue(self) -> list[tuple[str, str, str]]:
        """(job id, state, reason) of the jobs in squeue."""
        out = self.run("squeue", "--noheader", "--format=%i|%T|%r").stdout
        return [tuple(line.split("|", 2)) for line in out.splitlines() if line.strip()]

    def node_state(self, name: str) -> str:
        return self.run("sinfo", "--noheader", "--Node", f"--nodes={name}", "--format=%T").stdout.strip()

    def log(self, name: str) -> str:
        path = self.root / "log" / f"{name}.log"
        return path.read_text(errors="replace") if path.exists() else ""

    def logs_tail(self, chars: int = 3000) -> str:
        return "\n".join(
            f"--- {p.name}\n{p.read_text(errors='replace')[-chars:]}" for p in sorted((self.root / "log").glob("*.log"))
        )

    # ------------------------------------------------------------------ internals

    def _daemon(self, argv: list[str], name: str) -> None:
        log = open(self.root / "log" / f"{name}.out", "ab")
        self.procs.append(
            subprocess.Popen(
                argv,
                env=self.env,
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                preexec_fn=die_with_parent,
            )
        )

    def _nodes_idle(self) -> bool:
        for proc in self.procs:
            if proc.poll() is not None:
                raise AssertionError(f"{proc.args[0]} exited {proc.returncode} at start:\n{self.logs_tail()}")
        result = self.run("sinfo", "--noheader", "--Node", "--format=%N|%T", check=False)
        states = dict(line.split("|") for line in result.stdout.split())
        return len(states) == self.nodes and all(s == "idle" for s in states.values())

    def _wait(self, condition, timeout_s: float, what: str) -> None:
        deadline = time.monotonic() + timeout_s
        while not condition():
            if time.monotonic() > deadline:
                raise AssertionError(f"local SLURM: {what} within {timeout_s:.0f} s\n{self.logs_tail()}")
            time.sleep(0.2)
