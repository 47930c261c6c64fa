"""Start the gateway the way an operator does: the ``sovd-gateway`` console script."""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import psutil
import requests

from .procs import Proc, free_port, poll_until

BIN = Path(sys.executable).parent
PORT_ATTEMPTS = 3


class PortTaken(Exception):
    """Another server listens on the port a gateway was started on."""
SECRET_FLAGS = {"--api-token": "SOVD_API_TOKEN"}


class Gateway(Proc):
    """``sovd-gateway`` on a free loopback port with a private runtime dir.

    Waits until ``/api/v1/health`` answers with ``worker_alive: true``.  With
    ``log_path`` (the bench) its output goes to that file, not through a reader thread.
    """

    def __init__(self, *args: str, env: dict | None = None, timeout: float = 60.0,
                 runtime_dir: str | None = None, log_path: str | None = None):
        # A secret is never a flag (ps shows it): "--api-token X" goes in the environment, as an
        # operator puts it there.
        args, env = list(args), dict(env or {})
        for flag, variable in SECRET_FLAGS.items():
            while flag in args:
                at = args.index(flag)
                env[variable] = args[at + 1]
                del args[at:at + 2]
        # TLS (--tls-cert): requests check the server's certificate against that file.
        self.verify = args[args.index("--tls-cert") + 1] if "--tls-cert" in args else True
        self.scheme = "https" if "--tls-cert" in args else "http"
        # Under require_auth_for=all, /health wants a token: the legacy api_token is an admin's.
        token = env.get("SOVD_API_TOKEN")
        self.health_headers = {"Authorization": f"Bearer {token}"} if token else {}
        self._own_dir = runtime_dir is None
        self.runtime_dir = runtime_dir or tempfile.mkdtemp(prefix="sovd-gw-")
        os.chmod(self.runtime_dir, 0o700)
        # faults: a private state dir (the fault store), removed at stop, unless the test names one
        self.state_dir = args[args.index("--state-dir") + 1] if "--state-dir" in args else None
        self._own_state = self.state_dir is None
        if self._own_state:
            self.state_dir = tempfile.mkdtemp(prefix="sovd-state-")
            args = [*args, "--state-dir", self.state_dir]
        # A free port is free only when it is chosen: a gateway that another test started at the
        # same moment may take it first, and then answers this one's health check. Whether the
        # listener is this gateway's own is checked, and the start is tried again on a new port.
        for attempt in range(PORT_ATTEMPTS):
            self.port = free_port()
            self.url = f"{self.scheme}://127.0.0.1:{self.port}"
            self.api = self.url + "/api/v1"
            argv = [str(BIN / "sovd-gateway"), "--bind", f"127.0.0.1:{self.port}",
                    "--runtime-dir", self.runtime_dir, *args]
            super().__init__(argv, env=env, name="sovd-gateway", log_path=log_path)
            try:
                self._wait_ready(timeout)
            except PortTaken:
                self._stop_process()
                if attempt + 1 < PORT_ATTEMPTS:
                    continue
                self.stop()
                raise AssertionError(f"every port tried was taken by another server ({PORT_ATTEMPTS} tries)") from None
            except AssertionError:
                output = self.tail(60)
                self.stop()
                raise AssertionError("gateway did not become healthy; output:\n" + output) from None
            return

    def _stop_process(self) -> None:
        super().stop()

    def _wait_ready(self, timeout: float) -> None:
        """Until :meth:`_healthy`, and the listener is this gateway's (else :class:`PortTaken`)."""
        deadline = time.monotonic() + timeout
        last_error: Exception | None = None
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                output = self.tail(60)
                if "address already in use" in output:
                    raise PortTaken(self.port)
                raise AssertionError(f"sovd-gateway exited with {self.proc.returncode}:\n{output}")
            try:
                ready = self._healthy()
            except Exception as exc:  # not up yet
                last_error, ready = exc, False
            if ready:
                if self._listens_here():
                    return
                raise PortTaken(self.port)
            time.sleep(0.1)
        raise AssertionError(f"timed out after {timeout} s waiting for gateway health"
                             + (f" (last error: {last_error!r})" if last_error else ""))

    def _listens_here(self) -> bool:
        """Whether the process listening on this gateway's port is the gateway or one of its children."""
        ours = {self.pid, *(p.pid for p in self._children(recursive=True))}
        for conn in psutil.net_connections(kind="tcp"):
            if conn.status == psutil.CONN_LISTEN and conn.laddr and conn.laddr.port == self.port:
                if conn.pid in ours:
                    return True
        return False

    def _healthy(self) -> bool:
        r = requests.get(self.api + "/health", timeout=2, headers=self.health_headers, verify=self.verify)
        return r.status_code == 200 and r.json()["x-medkit-subscription-executor"]["worker_alive"]

    def host(self) -> str:
        """The id of the host component (every topic can be read through it)."""
        return self.get("/components").json()["items"][0]["id"]

    def rosworker_client(self):
        """A client of this gateway's ROS worker sockets (close it when done)."""
        from ipc.client import RosWorkerClient

        return RosWorkerClient.for_runtime_dir(self.runtime_dir)

    def rosworker_pid(self) -> int:
        return self.rosworker().pid

    def get(self, path: str, **kw) -> requests.Response:
        kw.setdefault("timeout", 15)
        kw.setdefault("verify", self.verify)
        return requests.get(self.api + path, **kw)

    def put(self, path: str, **kw) -> requests.Response:
        kw.setdefault("timeout", 15)
        kw.setdefault("verify", self.verify)
        return requests.put(self.api + path, **kw)

    def request(self, method: str, path: str, **kw) -> requests.Response:
        kw.setdefault("timeout", 15)
        kw.setdefault("verify", self.verify)
        return requests.request(method, self.api + path, **kw)

    def worker_sessions(self) -> dict[int, requests.Session]:
        """One keep-alive session per HTTP worker (each stays on the worker that took its connection),
        by the pid the debug route tells (start the gateway with ``--debug-commands``)."""
        sessions: dict[int, requests.Session] = {}

        def both() -> bool:
            s = requests.Session()
            pid = s.get(self.api + "/x-sovd-debug/worker", timeout=15, verify=self.verify).json()["pid"]
            if pid in sessions:
                s.close()
            else:
                sessions[pid] = s
            return len(sessions) == 2

        poll_until(both, 30, interval=0.01, message="a connection to each HTTP worker")
        return sessions

    def _children(self, recursive: bool = False) -> list[psutil.Process]:
        try:
            return psutil.Process(self.pid).children(recursive=recursive)
        except psutil.NoSuchProcess:
            return []

    def rosworker(self) -> psutil.Process:
        """The ROS worker process (a child of the supervisor)."""
        for p in self._children():
            try:
                if any("rosworker" in part for part in p.cmdline()):
                    return p
            except psutil.NoSuchProcess:
                continue
        raise RuntimeError("no ROS worker process under the gateway")

    def http_workers(self) -> list[psutil.Process]:
        """gunicorn's worker processes (children of the gunicorn master)."""
        for p in self._children():
            try:
                if "gunicorn" in " ".join(p.cmdline()):
                    return p.children()
            except psutil.NoSuchProcess:
                continue
        return []

    def worker_of(self, local_port: int) -> int:
        """The pid of the HTTP worker holding the client connection from ``local_port`` (once it shows)."""
        def find():
            for child in self._children(recursive=True):
                try:
                    for conn in child.net_connections(kind="tcp"):
                        if conn.raddr and conn.raddr.port == local_port:
                            return child.pid
                except psutil.Error:
                    continue
            return None
        return poll_until(find, 5, message="the HTTP worker of a connection")

    def stop(self, timeout: float = 15.0) -> int:
        code = super().stop(timeout)
        if self._own_dir:
            shutil.rmtree(self.runtime_dir, ignore_errors=True)
        if self._own_state:  # faults
            shutil.rmtree(self.state_dir, ignore_errors=True)
        return code


class FleetGateway(Gateway):
    """``sovd-gateway --fleet-aggregate`` (issue 34): healthy once ``/health`` says its fleet link answers
    (it has no ROS worker to wait for)."""

    def _healthy(self) -> bool:
        r = requests.get(self.api + "/health", timeout=2)
        return r.status_code == 200 and r.json()["x-medkit-fleet"]["link_alive"]

    def fleet_link(self):
        """The fleet-link process (the child that stands where a ROS worker would)."""
        for p in self._children():
            if any("fleetlink" in part for part in p.cmdline()):
                return p
        raise RuntimeError("no fleet link under the gateway")
