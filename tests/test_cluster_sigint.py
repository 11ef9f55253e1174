"""A terminal's Ctrl-C reaches every local dask worker process, the ones a nanny starts again
later included (on a loaded machine a worker caught mid-import printed a
KeyboardInterrupt traceback). Every spawned worker starts with SIGINT ignored; real
processes, read from /proc."""

from __future__ import annotations

import os
import signal
import sys
import time

import pytest

from pipeline.run.cluster.connection import connect
from pipeline.run.cluster.options import ClusterOptions

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/PID/status")


def _ignores_sigint(pid: int) -> bool:
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("SigIgn:"):
            return bool(int(line.split()[1], 16) & (1 << (signal.SIGINT - 1)))
    raise AssertionError(f"no SigIgn line for pid {pid}")


def _worker_pids(client) -> list[int]:
    return sorted(client.run(os.getpid).values())


@pytest.mark.slow
def test_local_workers_ignore_sigint_also_when_started_again_later():
    with connect(ClusterOptions(cluster="local", workers=1)) as conn:
        client = conn.client
        (first,) = _worker_pids(client)
        assert _ignores_sigint(first)
        # Started again after the cluster is up, as recycling or a memory restart does.
        client.restart_workers(list(client.scheduler_info()["workers"]))
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            pids = _worker_pids(client) if client.nthreads() else []
            if pids and pids != [first]:
                break
            time.sleep(0.2)
        (again,) = pids
        assert again != first
        assert _ignores_sigint(again)
        os.kill(again, signal.SIGINT)  # what a terminal's Ctrl-C sends it
        time.sleep(1.0)
        assert _worker_pids(client) == [again]  # still there, and answering
    assert _ignores_sigint(os.getpid()) is False  # the driver's Ctrl-C is its own
