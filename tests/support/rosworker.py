"""Start the real ``sovd-rosworker`` on a private runtime dir and talk to it over its socket."""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
import threading
from pathlib import Path

from common.harness.procs import Proc, poll_until
from ipc.client import RosWorkerClient
from ipc.errors import IpcError

BIN = Path(sys.executable).parent
SHADOW = Path(__file__).parent / "shadow"


def call_once(runtime_dir: str, cmd: str, args: dict | None = None, timeout: float = 5.0) -> dict:
    """One call to the ROS worker of ``runtime_dir`` (a gateway's too) on a client of its own, closed after."""
    client = RosWorkerClient.for_runtime_dir(runtime_dir)
    try:
        return client.call(cmd, args, timeout=timeout)
    finally:
        client.close()


class RosWorker(Proc):
    """``sovd-rosworker --runtime-dir <tmp> --<setting> <value> ...``; ready once it answers ping."""

    def __init__(self, runtime_dir: str | None = None, env: dict | None = None, wait: bool = True,
                 **settings):
        self._own_dir = runtime_dir is None
        self.runtime_dir = runtime_dir or tempfile.mkdtemp(prefix="sovd-rw-")
        argv = [str(BIN / "sovd-rosworker"), "--runtime-dir", self.runtime_dir]
        # The fault store of this worker: in its runtime dir (kept for a worker restarted on the
        # same dir), never the user's own state dir.
        settings.setdefault("state_dir", os.path.join(self.runtime_dir, "state"))
        for name, value in settings.items():
            flag = "--" + name.replace("_", "-")
            if value is True:
                argv.append(flag)
            else:
                argv += [flag, str(value)]
        super().__init__(argv, env=env, name="sovd-rosworker")
        self.client = RosWorkerClient.for_runtime_dir(self.runtime_dir)
        if wait:
            poll_until(self._pong, 30, interval=0.1, message="ROS worker ping")

    def _pong(self) -> bool:
        if self.proc.poll() is not None:
            raise AssertionError(f"sovd-rosworker exited with {self.proc.returncode}:\n"
                                 + "\n".join(self.output[-40:]))
        try:
            return bool(self.client.call("ping", timeout=0.5))
        except IpcError:
            return False

    def call(self, cmd: str, args: dict | None = None, timeout: float = 5.0) -> dict:
        return self.client.call(cmd, args, timeout=timeout)

    def stats(self) -> dict:
        return self.call("stats")

    def sample(self, topic: str, timeout_ms: int = 3000, **args) -> dict:
        return self.call("sample", {"topic": topic, "timeout_ms": timeout_ms, **args},
                         timeout=timeout_ms / 1000 + 5)

    def sample_data(self, topic: str, timeout: float = 15.0) -> dict:
        """Sample until the answer has data (the first read after discovery may be cold)."""
        return poll_until(lambda: (lambda r: r if r["status"] == "data" else None)(self.sample(topic)),
                          timeout, interval=0.1, message=f"data on {topic}")

    def cold_waiter(self, topic: str, timeout_ms: int = 20000) -> tuple[threading.Thread, list[dict]]:
        """Once ``topic`` (published, but quiet) is in the graph: a sample of it that waits for a message, on a
        thread of ours, counted as the worker's one cold waiter.  The thread, and the list its answer goes to."""
        poll_until(lambda: any(t["name"] == topic for t in self.call("graph")["topics"]), 10,
                   message=f"the publisher of {topic} discovered")
        answers: list[dict] = []
        waiter = threading.Thread(target=lambda: answers.append(self.sample(topic, timeout_ms=timeout_ms)))
        waiter.start()
        poll_until(lambda: self.stats()["data_provider"]["concurrent_cold_waits"] == 1, 5, message="cold waiter")
        return waiter, answers

    def busy(self, seconds: float) -> threading.Thread:
        """The ROS thread kept busy for ``seconds`` (``debug_sleep``: started with ``debug_commands``) by a call on
        a thread of ours, started."""
        call = threading.Thread(target=lambda: self.call("debug_sleep", {"seconds": seconds}, timeout=10))
        call.start()
        return call

    def stop(self, timeout: float = 10.0) -> int:
        code = super().stop(timeout)
        self.client.close()  # after the process: no thread of ours still waits on a reply
        if self._own_dir:
            shutil.rmtree(self.runtime_dir, ignore_errors=True)
        return code
