"""supervisor/sdnotify.py against real unix datagram sockets (path and abstract names)."""

from __future__ import annotations

import os
import socket
import time
import uuid

import pytest

from supervisor import sdnotify
from supervisor.sdnotify import Notifier, child_env


class Listener:
    """A unix datagram socket standing in for systemd's notify socket."""

    def __init__(self, address: str, rcvbuf: int | None = None):
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        if rcvbuf:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        self.sock.bind(address)
        self.sock.settimeout(2.0)

    def recv(self) -> str:
        return self.sock.recv(4096).decode()

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def path_listener(tmp_path):
    path = str(tmp_path / "notify.sock")
    lst = Listener(path)
    yield path, lst
    lst.close()


def test_no_notify_socket_is_a_no_op():
    n = Notifier({})
    assert not n.enabled
    assert n.watchdog_interval is None
    assert n.ready("x") is False
    assert n.watchdog() is False
    assert n.status("x") is False
    assert n.stopping() is False


def test_bad_notify_socket_value_is_ignored():
    n = Notifier({"NOTIFY_SOCKET": "relative/path"})
    assert not n.enabled
    assert n.ready() is False


def test_sequence_on_a_path_socket(path_listener):
    path, lst = path_listener
    n = Notifier({"NOTIFY_SOCKET": path})
    assert n.enabled
    assert n.status("starting ROS worker")
    assert n.ready("ROS worker pid 1 ready; gunicorn listening on http://127.0.0.1:8080")
    assert n.watchdog()
    assert n.watchdog()
    assert n.stopping("stopping")
    got = [lst.recv() for _ in range(5)]
    assert got == [
        "STATUS=starting ROS worker",
        "READY=1\nSTATUS=ROS worker pid 1 ready; gunicorn listening on http://127.0.0.1:8080",
        "WATCHDOG=1",
        "WATCHDOG=1",
        "STOPPING=1\nSTATUS=stopping",
    ]
    n.close()


def test_abstract_socket_name():
    name = f"sovd-test-{uuid.uuid4().hex}"
    lst = Listener("\0" + name)
    try:
        n = Notifier({"NOTIFY_SOCKET": "@" + name})
        assert n.ready()
        assert lst.recv() == "READY=1"
    finally:
        lst.close()


def test_newlines_in_status_cannot_forge_fields(path_listener):
    path, lst = path_listener
    n = Notifier({"NOTIFY_SOCKET": path})
    n.status("bad\nREADY=1")
    assert lst.recv() == "STATUS=bad READY=1"


def test_watchdog_interval_is_half_of_watchdog_usec(path_listener):
    path, _ = path_listener
    assert Notifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "2000000"}).watchdog_interval == 1.0
    # WATCHDOG_PID names another process: the watchdog is not ours to feed.
    assert Notifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "2000000",
                     "WATCHDOG_PID": str(os.getpid() + 1)}).watchdog_interval is None
    assert Notifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "2000000",
                     "WATCHDOG_PID": str(os.getpid())}).watchdog_interval == 1.0
    assert Notifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "junk"}).watchdog_interval is None
    assert Notifier({"WATCHDOG_USEC": "2000000"}).watchdog_interval is None  # no socket


def test_missing_receiver_does_not_raise(tmp_path):
    n = Notifier({"NOTIFY_SOCKET": str(tmp_path / "nobody.sock")})
    assert n.ready() is False
    assert n.watchdog() is False


def test_full_receiver_queue_does_not_block(tmp_path, monkeypatch):
    monkeypatch.setattr(sdnotify, "SEND_TIMEOUT", 0.2)
    lst = Listener(str(tmp_path / "full.sock"), rcvbuf=1024)
    try:
        n = Notifier({"NOTIFY_SOCKET": str(tmp_path / "full.sock")})
        started = time.monotonic()
        sent = 0
        while n.status("x" * 200):
            sent += 1
            assert sent < 100000, "a receiver that never reads must make a send fail, not block"
        assert time.monotonic() - started < 60  # hang catcher only
    finally:
        lst.close()


def test_child_env_drops_notify_variables():
    env = {"NOTIFY_SOCKET": "@x", "WATCHDOG_USEC": "1", "WATCHDOG_PID": "2", "PATH": "/bin"}
    assert child_env(env) == {"PATH": "/bin"}
