"""Builds on a real dask cluster on loopback: a `dask scheduler` and two `dask worker`
processes, `shaderball build --scheduler`; a worker SIGKILLed in the middle of a shard costs
only that shard's unfinished samples. Also worker recycling and the memory probe
(docs/cluster.md). Every process started here is killed, with its group, even on failure.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipeline.errors import ShaderballError
from pipeline.run.cluster.options import ClusterOptions
from support import VARIANT
from support.clusters import DASK, SHADERBALL, start_group, start_scheduler

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "manifests" / "smoke.toml"


from conftest import crash_module  # noqa: E402

crash = crash_module()


@pytest.fixture
def dask_cluster(tmp_path):
    """(address, [processes]): a scheduler and 2 single-thread workers on 127.0.0.1."""
    from distributed import Client

    procs = []
    try:
        address = start_scheduler(tmp_path, procs)
        for i in range(2):
            procs.append(
                start_group(
                    [
                        DASK,
                        "worker",
                        "--scheduler-file",
                        str(tmp_path / "scheduler.json"),
                        "--host",
                        "127.0.0.1",
                        "--nthreads",
                        "1",
                        "--no-dashboard",
                        "--memory-limit",
                        "4GiB",
                        "--death-timeout",
                        "60",
                        "--name",
                        f"w{i}",
                    ],
                    tmp_path / f"worker{i}.log",
                    env={"SHADERBALL_RENDER_THREADS": "1"},
                )
            )
        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=120)
        yield address, procs
    finally:
        for proc in reversed(procs):
            crash.kill_group(proc)


def _shard_in_progress(out: Path, client) -> tuple[str, str] | None:
    """(worker address, shard id) of a shard with a record on disk and no marker yet."""
    for worker, keys in client.processing().items():
        for key in keys:
            match = re.match(r"shard-(s\d+)-", str(key))
            if not match:
                continue
            folder = out / "shards" / match[1]
            if (
                folder.is_dir()
                and not (folder / "COMPLETE.json").exists()
                and any(re.fullmatch(r"m\d+_l\d+\.json", n) for n in os.listdir(folder))
            ):
                return worker, match[1]
    return None


@pytest.mark.slow
def test_build_on_a_scheduler_survives_a_worker_killed_mid_shard(tmp_path, reference, dask_cluster):
    from distributed import Client

    address, _procs = dask_cluster
    out = tmp_path / "ds"
    build = start_group(
        [*SHADERBALL, "build", str(SMOKE), "--out", str(out), "--scheduler", address], tmp_path / "build.log"
    )
    try:
        with Client(address, timeout="30s") as client:
            deadline = time.monotonic() + 240
            found = None
            while found is None:
                assert build.poll() is None, (tmp_path / "build.log").read_text()
                assert time.monotonic() < deadline, "no shard was seen in progress"
                found = _shard_in_progress(out, client)
                time.sleep(0.05)
            worker, shard = found
            pid = client.run(os.getpid, workers=[worker])[worker]
            os.kill(pid, signal.SIGKILL)
            committed = {p.name: p.stat().st_mtime_ns for p in (out / "shards" / shard).glob("m*_l*.json")}
        assert build.wait(timeout=300) == 0, (tmp_path / "build.log").read_text()
    finally:
        crash.kill_group(build)
    assert committed, "the worker was killed before its shard committed a sample"
    # The shard ran again elsewhere; the samples the killed worker had committed were kept.
    for name, mtime in committed.items():
        assert (out / "shards" / shard / name).stat().st_mtime_ns == mtime, name
    assert "rendered 16, already present 0" in (tmp_path / "build.log").read_text()
    crash.check_complete(out, reference)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_unreachable_scheduler_fails_fast_and_writes_nothing(tmp_path, monkeypatch):
    """Fast by construction, not by a clock: one connection attempt with a short timeout before
    anything else (dask's client would retry for its own 30 s)."""
    from pipeline.run.build import build

    attempts, connect = [], socket.create_connection

    def counted(address, timeout=None, *args, **kwargs):
        attempts.append((address, timeout))
        return connect(address, timeout, *args, **kwargs)

    monkeypatch.setattr(socket, "create_connection", counted)
    out, port = tmp_path / "ds", _free_port()
    with pytest.raises(ShaderballError, match=r'scheduler: cannot reach "tcp://127.0.0.1:\d+"'):
        build(str(SMOKE), str(out), cluster=ClusterOptions(scheduler=f"tcp://127.0.0.1:{port}"))
    assert [(address, timeout <= 10) for address, timeout in attempts] == [(("127.0.0.1", port), True)], attempts
    assert not out.exists()


@pytest.mark.parametrize("address", ["127.0.0.1:8786", "tcp://host", "http://h:1", "tcp://h:70000"])
def test_bad_scheduler_address_is_refused(address):
    with pytest.raises(ShaderballError, match=r"scheduler: .* is not allowed; tcp://HOST:PORT"):
        ClusterOptions(scheduler=address)


def test_a_worker_that_cannot_see_the_dataset_refuses_the_shard(tmp_path):
    from pipeline.dataset.plan import plan_dataset
    from pipeline.dataset.spec_file import parse_spec
    from pipeline.run.shard import run_shard_in_process

    spec = parse_spec(SMOKE)
    with pytest.raises(ShaderballError, match="same path on a shared filesystem"):
        run_shard_in_process(str(tmp_path / "elsewhere"), spec, plan_dataset(spec)[0], VARIANT, 1)


@pytest.mark.slow
def test_recycled_workers_build_the_same_dataset(tmp_path, reference):
    """--recycle-after 4: a fresh worker process after every shard (4 renders); nothing lost."""
    from pipeline.run.build import build

    out = tmp_path / "ds"
    summary = build(str(SMOKE), str(out), cluster=ClusterOptions(workers=1, recycle_after=4))
    assert summary.rendered == 16
    assert summary.recycled >= 1  # logged by the workers; their last results may be lost (re-run)
    crash.check_complete(out, reference)


def test_memory_probe_reports_growth():
    probe = [sys.executable, str(REPO / "scripts" / "memory_probe.py")]
    done = subprocess.run(
        [*probe, "--memory-probe", "4", "--resolution", "16", "--spp", "1", "--every", "2"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr
    assert "memory probe: 4 renders at 16x16" in done.stdout and "MiB per 100 renders" in done.stdout
    refused = subprocess.run([*probe, "--memory-probe", "1"], capture_output=True, text=True, timeout=600)
    assert refused.returncode == 2 and "--memory-probe: 1 is not allowed" in refused.stderr


def _logging_disabled_level() -> int:
    import logging

    return logging.root.manager.disable


def test_an_interrupted_local_cluster_is_silenced_on_every_worker_and_this_process_is_restored():
    """Ctrl-C: workers and this process stop logging before the cluster closes (their heartbeat
    errors buried the one-line message on a loaded machine); afterwards logging is back."""
    import logging

    from pipeline.run.cluster.connection import connect

    with pytest.raises(KeyboardInterrupt):
        with connect(ClusterOptions(workers=2, start_timeout=120)) as conn:
            assert set(conn.client.run(_logging_disabled_level).values()) == {logging.NOTSET}
            raise KeyboardInterrupt

    assert _logging_disabled_level() == logging.NOTSET  # restored once the cluster closed


def test_quiet_for_shutdown_reaches_the_workers_of_a_local_cluster():
    import logging

    from distributed import Client, LocalCluster

    from pipeline.run.cluster.connection import quiet_for_shutdown

    before = _logging_disabled_level()
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster:
        with Client(cluster) as client:
            try:
                quiet_for_shutdown(client, workers_too=True)
                assert _logging_disabled_level() == logging.CRITICAL
                assert set(client.run(_logging_disabled_level).values()) == {logging.CRITICAL}
            finally:
                logging.disable(before)
