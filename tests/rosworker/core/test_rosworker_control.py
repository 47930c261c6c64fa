"""The ROS worker's control thread and the counters it reads (``ipc/server.py``, ``rosworker/core/stats.py``).

``stats`` is answered by the control thread from counters the ROS thread
writes.  A snapshot taken while the ROS thread counts a command name it has
not seen before must not fail (issue 18: "dictionary changed size during
iteration"), and should the control thread's answer fail all the same, that
request gets ``internal`` and the thread goes on answering: a dead control
thread leaves a healthy worker silent, and the supervisor kills it.

These run in-process: the two threads are real and so are the socket and the
client (``ipc/client.py``), but the Stats of the second test fails on purpose.
"""

from __future__ import annotations

import sys
import tempfile
import threading

import pytest
import zmq

from app.core.errors import ApiError
from ipc.client import RosWorkerClient
from ipc.errors import IpcError
from ipc.server import ControlServer
from rosworker.core.stats import Stats

NEW_NAMES = 2000  # command names the "ROS thread" counts for the first time
REPEATS = 50      # commands counted under names it has seen, after each new one


def _stats() -> Stats:
    return Stats(pool_cap=1, cold_wait_cap=1, watchdog_threshold_ms=1000)


def test_a_snapshot_never_fails_while_the_ros_thread_counts_new_command_names():
    stats = _stats()
    errors: list[BaseException] = []
    snapshots = 0

    def ros_thread() -> None:  # what the executor does at the end of each command (task_finished)
        for i in range(NEW_NAMES):
            stats.task_finished(stats.task_started(), True, f"cmd_{i}")
            for j in range(REPEATS):
                stats.task_finished(stats.task_started(), True, f"cmd_{j * i // REPEATS}")

    switch = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # switch threads as often as possible: the race shows at once
    writer = threading.Thread(target=ros_thread)
    try:
        writer.start()
        while writer.is_alive():
            try:
                stats.snapshot()
            except RuntimeError as exc:
                errors.append(exc)
                break
            snapshots += 1
    finally:
        writer.join(60)
        sys.setswitchinterval(switch)
    assert not errors, errors
    assert snapshots > 0  # the snapshots were taken while names were being added
    assert len(stats.snapshot()["details"]["commands"]) == NEW_NAMES


class FailingSnapshot(Stats):
    """Stats whose next ``failures`` snapshots raise, as a bug in them would."""

    failures = 0

    def snapshot(self) -> dict:
        if self.failures:
            self.failures -= 1
            raise RuntimeError("dictionary changed size during iteration")
        return super().snapshot()


@pytest.fixture
def control():
    runtime_dir = tempfile.mkdtemp(prefix="sovd-ctl-")
    zctx = zmq.Context()
    stats = FailingSnapshot(pool_cap=1, cold_wait_cap=1, watchdog_threshold_ms=1000)
    server = ControlServer(zctx, runtime_dir, stats, {"version": "test"})
    server.start()
    client = RosWorkerClient.for_runtime_dir(runtime_dir)
    yield server, stats, client
    client.close()
    server.finish()
    zctx.term()


def test_a_failed_answer_is_answered_internal_and_the_control_thread_answers_on(control):
    server, stats, client = control
    assert client.call("stats", timeout=2)["executor"]["worker_alive"]
    stats.failures = 1
    with pytest.raises(IpcError) as info:
        client.call("stats", timeout=2)
    assert info.value.code == "internal", info.value
    assert ApiError.from_ipc(info.value).status == 500
    assert server.errors == 1
    # the same thread answers the next requests (before: it had died, so they timed out)
    assert client.call("ping", timeout=2)["version"] == "test"
    assert client.call("stats", timeout=2)["executor"]["worker_alive"]
    assert server._thread.is_alive()
