"""The processes of a bench run: its private ROS domain, the gateway, the helper nodes.

- :func:`claim_domain` takes a ``ROS_DOMAIN_ID`` that no test session or other
  bench holds (the same ``flock`` files as ``tests/conftest.py``) and sets
  localhost-only discovery, so the bench never sees another robot.
- :class:`BenchGateway` starts the real ``sovd-gateway`` console script; its
  output goes to a log file, not through a Python reader (a reader thread
  would take CPU from what is measured).
- :func:`ros_helper` starts ``python -m tests.support.<module>`` and waits for ``READY``.
"""

from __future__ import annotations

import fcntl
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil
import requests

from tests.support.procs import REPO, Proc, free_port, poll_until

BIN = Path(sys.executable).parent
DOMAIN_LOCK_DIR = "/tmp/sovd-gateway-test-domains"
_held: list = []


def claim_domain() -> int:
    """Claim a free ROS domain (1–100) for this process and its children."""
    os.makedirs(DOMAIN_LOCK_DIR, exist_ok=True)
    candidates = list(range(1, 101))
    random.shuffle(candidates)
    for domain in candidates:
        fh = open(os.path.join(DOMAIN_LOCK_DIR, f"{domain}.lock"), "w")  # noqa: SIM115 - held
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.close()
            continue
        _held.append(fh)
        os.environ["ROS_DOMAIN_ID"] = str(domain)
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        os.environ.pop("ROS_STATIC_PEERS", None)
        os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
        os.environ["PYTHONUNBUFFERED"] = "1"
        # Tests that run inside a bench (the smoke test) must not claim another domain.
        os.environ["SOVD_TEST_DOMAIN_CLAIMED"] = "1"
        return domain
    raise RuntimeError("no free ROS_DOMAIN_ID in 1..100")


def ros_helper(module: str, *args: str, name: str | None = None, timeout: float = 60.0) -> Proc:
    """``python -m tests.support.<module> ARGS`` in its own process; returns once it printed READY.

    The bench's ROS nodes live beside the tests' own (only ``rosworker/`` of the
    gateway may create ROS entities; tests/test_layout.py).
    """
    proc = Proc([sys.executable, "-m", f"tests.support.{module}", *args], name=name or module)
    proc.wait_line(lambda line: line == "READY", timeout)
    return proc


def robot(node: str, groups: list[dict], timeout: float = 60.0) -> Proc:
    return ros_helper("benchpub", json.dumps({"node": node, "groups": groups}), name=node, timeout=timeout)


class BenchGateway:
    """``sovd-gateway --bind 127.0.0.1:<free port> --runtime-dir <tmp> ARGS``."""

    def __init__(self, *args: str, log_dir: str, timeout: float = 60.0):
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.api = self.url + "/api/v1"
        self.runtime_dir = tempfile.mkdtemp(prefix="sovd-bench-")
        os.chmod(self.runtime_dir, 0o700)
        self.log_path = os.path.join(log_dir, "gateway.log")
        self._log = open(self.log_path, "w")  # noqa: SIM115 - closed in stop()
        argv = [str(BIN / "sovd-gateway"), "--bind", f"127.0.0.1:{self.port}",
                "--runtime-dir", self.runtime_dir, *args]
        self.proc = subprocess.Popen(argv, stdout=self._log, stderr=subprocess.STDOUT, cwd=REPO,
                                     start_new_session=True, stdin=subprocess.DEVNULL)
        try:
            poll_until(self._healthy, timeout, interval=0.1, message="gateway health")
        except AssertionError:
            self.stop()
            raise RuntimeError("the gateway did not become healthy; see " + self.log_path) from None

    def _healthy(self) -> bool:
        if self.proc.poll() is not None:
            raise RuntimeError(f"sovd-gateway exited with {self.proc.returncode}; see {self.log_path}")
        r = requests.get(self.api + "/health", timeout=2)
        return r.status_code == 200 and r.json()["x-medkit-subscription-executor"]["worker_alive"]

    def _tree(self) -> list[psutil.Process]:
        try:
            return psutil.Process(self.proc.pid).children(recursive=True)
        except psutil.NoSuchProcess:
            return []

    def rosworker(self) -> psutil.Process:
        for p in self._tree():
            try:
                if any("rosworker" in part for part in p.cmdline()):
                    return p
            except psutil.NoSuchProcess:
                continue
        raise RuntimeError("no ROS worker process under the gateway")

    def http_workers(self) -> list[psutil.Process]:
        """gunicorn's worker processes (children of the gunicorn master)."""
        for p in self._tree():
            try:
                if "gunicorn" in " ".join(p.cmdline()) and p.ppid() == self.proc.pid:
                    return p.children()
            except psutil.NoSuchProcess:
                continue
        return []

    def stop(self, timeout: float = 15.0) -> None:
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
        self._log.close()
        shutil.rmtree(self.runtime_dir, ignore_errors=True)


def cpu_seconds(proc: psutil.Process) -> float:
    t = proc.cpu_times()
    return t.user + t.system


def measure_cpu(procs: dict[str, psutil.Process], seconds: float) -> dict[str, float]:
    """Share of one core each process used over the same ``seconds`` window."""
    before = {k: cpu_seconds(p) for k, p in procs.items()}
    start = time.monotonic()
    time.sleep(seconds)
    wall = time.monotonic() - start
    return {k: (cpu_seconds(p) - before[k]) / wall for k, p in procs.items()}
