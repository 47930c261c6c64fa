"""Start and stop real processes for tests, always with a deadline."""

from __future__ import annotations

import json
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def poll_until(predicate: Callable[[], object], timeout: float, interval: float = 0.05,
               message: str = "condition") -> object:
    """Call ``predicate`` until it returns something truthy; fail after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    last_exc = None
    while time.monotonic() < deadline:
        try:
            value = predicate()
            if value:
                return value
        except Exception as exc:  # the thing polled may not be up yet
            last_exc = exc
        time.sleep(interval)
    raise AssertionError(f"timed out after {timeout} s waiting for {message}"
                         + (f" (last error: {last_exc!r})" if last_exc else ""))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Proc:
    """A child process whose stdout lines are collected by a reader thread."""

    def __init__(self, argv: list[str], env: dict | None = None, name: str = "proc"):
        self.name = name
        self.lines: queue.Queue[str] = queue.Queue()
        self.output: list[str] = []
        self.proc = subprocess.Popen(
            argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            env={**os.environ, **(env or {})}, cwd=REPO, start_new_session=True,
        )
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            line = line.rstrip("\n")
            self.output.append(line)
            self.lines.put(line)

    @property
    def pid(self) -> int:
        return self.proc.pid

    def wait_line(self, predicate: Callable[[str], bool], timeout: float) -> str:
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(f"{self.name}: no matching line within {timeout} s; output:\n"
                                     + "\n".join(self.output[-40:]))
            try:
                line = self.lines.get(timeout=min(remaining, 0.2))
            except queue.Empty:
                if self.proc.poll() is not None and self.lines.empty():
                    raise AssertionError(f"{self.name} exited with {self.proc.returncode}; output:\n"
                                         + "\n".join(self.output[-40:])) from None
                continue
            if predicate(line):
                return line

    def signal(self, sig: int) -> None:
        if self.proc.poll() is None:
            os.kill(self.proc.pid, sig)

    def stop(self, timeout: float = 10.0) -> int:
        """SIGTERM, wait up to ``timeout``, then SIGKILL the whole process group."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                pass
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        self.proc.wait(timeout=5)
        self._reader.join(timeout=2)
        return self.proc.returncode


class RosNode(Proc):
    """A real rclpy node in another process (``tests/support/rospub.py``)."""

    def __init__(self, spec: dict, timeout: float = 20.0):
        super().__init__([sys.executable, "-m", "tests.support.rospub", json.dumps(spec)],
                         name=f"rosnode {spec.get('node')}")
        self.wait_line(lambda line: line == "READY", timeout)

    def echoed(self) -> list[dict]:
        out = []
        for line in self.output:
            if line.startswith("{"):
                out.append(json.loads(line))
        return out


def publisher(node: str, topic: str, type_: str, value: dict | None = None, rate: float = 10,
              namespace: str = "/", **options) -> RosNode:
    """One node publishing one topic: the common case."""
    item = {"topic": topic, "type": type_, "rate": rate, "value": value or {}, **options}
    return RosNode({"node": node, "namespace": namespace, "publish": [item]})
