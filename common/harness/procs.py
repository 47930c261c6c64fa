"""Start and stop real processes for the tests and the bench, always with a deadline.

- :func:`private_ros_domain`: a ``ROS_DOMAIN_ID`` of this process's own (a ``flock``
  per id, held for the process's life) and localhost-only discovery, inherited by
  every child; a test session and a bench run each call it once.
- :class:`Proc`: a child process whose output is collected line by line (or, for
  the bench, written to a file, so that no reader thread takes CPU from what is
  measured); :func:`poll_until`: wait for a condition to a deadline.
"""

from __future__ import annotations

import fcntl
import os
import queue
import random
import signal
import socket
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO

REPO = Path(__file__).resolve().parents[2]
DOMAIN_LOCK_DIR = "/tmp/sovd-gateway-test-domains"
_domain_locks: list = []  # held for the life of the process


def _claim(lock_dir: str, numbers: range) -> tuple[int, IO[str]] | None:
    """One of ``numbers``, tried in random order, whose lock file in ``lock_dir`` this process could ``flock``,
    with that file (the lock lasts while it is open); None when every one is held."""
    os.makedirs(lock_dir, exist_ok=True)
    candidates = list(numbers)
    random.shuffle(candidates)
    for number in candidates:
        fh = open(os.path.join(lock_dir, f"{number}.lock"), "w")  # noqa: SIM115 - held
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.close()
            continue
        return number, fh
    return None


def claim_domain() -> int:
    """A ROS_DOMAIN_ID (1–100) that no other test session or bench on this machine holds."""
    claimed = _claim(DOMAIN_LOCK_DIR, range(1, 101))
    if claimed is None:
        raise RuntimeError("no free ROS_DOMAIN_ID in 1..100")
    domain, fh = claimed
    _domain_locks.append(fh)
    return domain


def private_ros_domain() -> int:
    """Put this process and its children in a ROS domain of their own, discovery on localhost.

    Call it before anything imports rclpy.  A process started by one that has
    already claimed a domain (``SOVD_TEST_DOMAIN_CLAIMED`` in its environment:
    a bench inside the smoke test) keeps its parent's.  A pytest-xdist worker
    is a test session of its own: it claims its own domain rather than share
    the one its controller claimed.
    """
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if "SOVD_TEST_DOMAIN_CLAIMED" not in os.environ or os.environ.get("SOVD_TEST_DOMAIN_SESSION") != worker:
        os.environ["ROS_DOMAIN_ID"] = str(claim_domain())
        os.environ["SOVD_TEST_DOMAIN_CLAIMED"] = "1"
        os.environ["SOVD_TEST_DOMAIN_SESSION"] = worker
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_STATIC_PEERS", None)
    os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    os.environ["PYTHONUNBUFFERED"] = "1"
    return int(os.environ["ROS_DOMAIN_ID"])


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


PORT_LOCK_DIR = "/tmp/sovd-gateway-test-ports"
PORT_BLOCKS = range(12000, 32000, 200)  # below the kernel's ephemeral range (32768-60999)
_port_block: list = []  # [lock file, ports of the block, next index, pid], held for the life of the process


def free_port() -> int:
    """A loopback TCP port that is free now, from a block of ports this process alone hands out.

    The kernel's ``bind(0)`` may hand the same port to two test sessions (xdist workers) at once,
    and either may take it first; a block held by ``flock`` (as a ROS domain is) and below the
    ephemeral range (where outgoing connections take their ports) makes that impossible between
    processes that use this function.
    """
    if _port_block and _port_block[3] != os.getpid():  # a forked child: a block of its own
        _port_block.clear()
    if not _port_block:
        claimed = _claim(PORT_LOCK_DIR, PORT_BLOCKS)
        if claimed is None:
            raise RuntimeError(f"every block of test ports in {PORT_LOCK_DIR} is held")
        start, fh = claimed
        _port_block.extend([fh, range(start, start + PORT_BLOCKS.step), 0, os.getpid()])
    ports = _port_block[1]
    for _ in range(len(ports)):
        port = ports[_port_block[2] % len(ports)]
        _port_block[2] += 1
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue  # a server of something else, or a connection of ours in TIME_WAIT
            return port
    raise RuntimeError(f"no free port in {ports.start}..{ports.stop - 1}")


class Proc:
    """A child process whose stdout lines are collected by a reader thread (``stdin``: a pipe to
    write commands to, ``proc.stdin``, text).  ``with Proc(...) as p:`` stops it at the block's end.

    With ``log_path`` its output goes to that file instead (no reader thread;
    :meth:`wait_line` is then not available, :meth:`tail` reads the file).
    """

    def __init__(self, argv: list[str], env: dict | None = None, name: str = "proc",
                 log_path: str | None = None, stdin: bool | int | None = None):
        self.name = name
        self.lines: queue.Queue[str] = queue.Queue()
        self.output: list[str] = []
        self.log_path = log_path
        self._log = open(log_path, "w") if log_path else None  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen(
            argv, stdout=self._log or subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            env={**os.environ, **(env or {})}, cwd=REPO, start_new_session=True,
            stdin=(subprocess.PIPE if stdin is True else stdin if stdin not in (None, False)
                   else subprocess.DEVNULL if log_path else None),
        )
        self._reader = None
        if self._log is None:
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

    def tail(self, n: int = 40) -> str:
        """The last ``n`` lines of output."""
        if self.log_path:
            with open(self.log_path, errors="replace") as fh:
                return "".join(fh.readlines()[-n:])
        return "\n".join(self.output[-n:])

    def wait_line(self, predicate: Callable[[str], bool], timeout: float) -> str:
        if self._reader is None:
            raise RuntimeError(f"{self.name}: output goes to {self.log_path}, not read line by line")
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

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

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
        if self._reader is not None:
            self._reader.join(timeout=2)
        if self._log is not None:
            self._log.close()
        return self.proc.returncode
