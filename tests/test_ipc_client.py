"""The fork-safe IPC client against the real ROS worker: deadlines, dead workers, forks."""

from __future__ import annotations

import os
import threading
import time

import pytest

from ipc.client import RosWorkerClient
from ipc.errors import IpcError
from tests.support.rosworker import RosWorker


def test_a_request_lost_with_a_killed_worker_is_unavailable_at_once_not_a_timeout():
    worker = RosWorker(debug_commands=True)
    client = RosWorkerClient.for_runtime_dir(worker.runtime_dir)
    try:
        outcome: list = []

        def call():
            started = time.monotonic()
            try:
                client.call("debug_sleep", {"seconds": 30}, timeout=20)
            except IpcError as exc:
                outcome.append((exc, time.monotonic() - started))

        t = threading.Thread(target=call)
        t.start()
        time.sleep(0.5)
        worker.signal(9)
        t.join(25)
        exc, waited = outcome[0]
        assert exc.code == "unavailable" and exc.status == 503
        assert waited < 10  # not the 20 s deadline
    finally:
        client.close()
        worker.stop()


def test_no_worker_is_unavailable_and_a_silent_worker_is_a_deadline(tmp_path):
    client = RosWorkerClient.for_runtime_dir(str(tmp_path))
    try:
        with pytest.raises(IpcError) as info:
            client.call("ping", timeout=1)
        assert info.value.code == "unavailable"
    finally:
        client.close()
    worker = RosWorker(debug_commands=True)
    client = RosWorkerClient.for_runtime_dir(worker.runtime_dir)
    try:
        threading.Thread(target=lambda: worker.client.call("debug_sleep", {"seconds": 3}, timeout=10),
                         daemon=True).start()
        time.sleep(0.3)
        with pytest.raises(IpcError) as info:
            client.call("pool", timeout=0.5)
        assert info.value.code == "deadline-exceeded" and info.value.status == 504
        # The late reply to the timed-out call is dropped: the next call gets its own answer.
        time.sleep(3)
        assert client.call("pool", timeout=5) == {"topics": []}
        assert client.call("ping")["pid"] == worker.pid
    finally:
        client.close()
        worker.stop()


def test_a_forked_child_makes_its_own_context():
    worker = RosWorker()
    client = RosWorkerClient.for_runtime_dir(worker.runtime_dir)
    try:
        parent_pid = client.call("ping")["pid"]
        child = os.fork()
        if child == 0:  # pragma: no cover - runs in the child
            try:
                ok = client.call("ping", timeout=5)["pid"] == parent_pid
            except Exception:
                ok = False
            os._exit(0 if ok else 1)
        _, status = os.waitpid(child, 0)
        assert os.WEXITSTATUS(status) == 0
        assert client.call("ping")["pid"] == parent_pid  # the parent's socket still works
    finally:
        client.close()
        worker.stop()
