"""The supervisor's children: how they are started, probed and killed.

A :class:`Child` runs in its own process group (Ctrl-C in a terminal reaches
only the supervisor, which stops the children in order) with a parent-death
signal, so a supervisor killed outright does not leave it behind.  Nothing
runs between fork and exec: the child arms that signal itself, from its
environment (``common/pdeathsig.py``).
"""

from __future__ import annotations

import errno
import http.client
import os
import signal
import socket
import subprocess
import sys
from typing import IO

from common import pdeathsig


class Child:
    """One child process in its own process group, killed if the supervisor dies.

    ``death_signal`` is what the child arms against the supervisor (``common/pdeathsig.py``);
    the child's program must call ``pdeathsig.arm()`` first thing.
    """

    def __init__(self, name: str, argv: list[str], env: dict[str, str], death_signal: int,
                 output: IO[str] | None = None):
        self.name = name
        self.output = output  # where its stdout and stderr go (None: the supervisor's own)
        self.argv = argv
        self.env = env
        self.death_signal = death_signal
        self.proc: subprocess.Popen | None = None

    def start(self) -> None:
        env = {**self.env, **pdeathsig.child_env(self.death_signal)}
        self.proc = subprocess.Popen(self.argv, env=env, stdin=subprocess.DEVNULL, process_group=0,
                                     stdout=self.output, stderr=subprocess.STDOUT if self.output else None)

    @property
    def pid(self) -> int:
        return self.proc.pid

    @property
    def returncode(self) -> int | None:
        return self.proc.poll()

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def send(self, sig: int) -> None:
        if self.alive():
            try:
                os.kill(self.proc.pid, sig)
            except ProcessLookupError:
                pass

    def kill_group(self) -> None:
        """SIGKILL the child and everything left in its process group (its own children)."""
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass

    def describe_exit(self) -> str:
        code = self.proc.returncode
        if code is not None and code < 0:
            try:
                return f"was killed by {signal.Signals(-code).name}"
            except ValueError:
                return f"was killed by signal {-code}"
        return f"exited with code {code}"


def _split_bind(bind: str) -> tuple[str, int]:
    host, _, port = bind.rpartition(":")
    return host.strip("[]"), int(port)


def bind_problem(bind: str) -> str | None:
    """Why gunicorn could not listen on ``bind`` (e.g. address in use), or None."""
    host, port = _split_bind(bind)
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as exc:
        return f"cannot resolve {host!r}: {exc.strerror}"
    family, kind, proto, _, addr = infos[0]
    with socket.socket(family, kind, proto) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(addr)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                return "address already in use (another gateway or server listens there)"
            return exc.strerror or str(exc)
    return None


def http_answers(bind: str, timeout: float = 2.0, tls: bool = False) -> bool:
    """True when something on ``bind`` answers an HTTP request (any status; over TLS with ``tls``,
    whatever its certificate: this only asks whether gunicorn is up)."""
    host, port = _split_bind(bind)
    if host in ("", "0.0.0.0"):
        host = "127.0.0.1"
    elif host == "::":
        host = "::1"
    if tls:
        import ssl

        context = ssl.create_default_context()
        context.check_hostname = False
        context.verify_mode = ssl.CERT_NONE
        conn: http.client.HTTPConnection = http.client.HTTPSConnection(host, port, timeout=timeout, context=context)
    else:
        conn = http.client.HTTPConnection(host, port, timeout=timeout)
    try:
        conn.request("GET", "/api/v1/health")
        conn.getresponse().read()
        return True
    except (OSError, http.client.HTTPException):
        return False
    finally:
        conn.close()


def rosworker_argv(runtime_dir: str) -> list[str]:
    """``sovd-rosworker --runtime-dir DIR``: the console script next to our interpreter."""
    script = os.path.join(os.path.dirname(sys.executable), "sovd-rosworker")
    if os.access(script, os.X_OK):
        return [sys.executable, script, "--runtime-dir", runtime_dir]
    return [sys.executable, "-m", "rosworker.main", "--runtime-dir", runtime_dir]


def gunicorn_argv() -> list[str]:
    return [sys.executable, "-m", "gunicorn", "-c", "python:app.gunicorn_conf", "app.wsgi:create_app()"]
