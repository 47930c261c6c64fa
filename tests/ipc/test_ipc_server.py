"""ipc/server.py: the runtime lock, the private sockets, and what the control thread answers.

Real files, real flocks (one holder in another process), real ZeroMQ sockets
and the real client (``ipc/client.py``).  The control thread's containment of a
failing answer is in tests/rosworker/core/test_rosworker_control.py; the work socket, served
by the ROS thread, in tests/rosworker/core/test_rosworker_executor.py.
"""

from __future__ import annotations

import os
import stat
import subprocess
import sys
import time

import pytest
import zmq

from common.harness.procs import poll_until
from ipc import events, protocol
from ipc.client import RosWorkerClient
from ipc.server import ControlServer, LockHeld, RuntimeLock, bind_publisher
from rosworker.core.stats import Stats

HOLD = """
import sys, time
from ipc.server import RuntimeLock
lock = RuntimeLock(sys.argv[1])
lock.acquire()  # held until this process dies
print("held", flush=True)
time.sleep(60)
"""


def mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


# ---------------------------------------------------------------- RuntimeLock


def test_the_lock_is_exclusive_and_free_again_once_released(tmp_path):
    first = RuntimeLock(str(tmp_path))
    first.acquire()
    assert open(first.path).read() == str(os.getpid())
    assert mode(first.path) == 0o600
    second = RuntimeLock(str(tmp_path))
    with pytest.raises(LockHeld) as info:
        second.acquire()  # another open file: flock refuses it even in the same process
    assert f"pid {os.getpid()}" in str(info.value) and str(tmp_path) in str(info.value)
    first.release()
    second.acquire()
    second.release()


def test_a_lock_held_by_another_process_names_it_and_is_freed_when_it_dies(tmp_path):
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(tmp_path)], stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": os.getcwd()})
    try:
        assert holder.stdout.readline().strip() == "held"
        lock = RuntimeLock(str(tmp_path))
        with pytest.raises(LockHeld) as info:
            lock.acquire()
        assert f"pid {holder.pid}" in str(info.value)
        holder.kill()  # killed outright: the kernel drops its flock
        holder.wait(10)
        lock.acquire()
        assert open(lock.path).read() == str(os.getpid())  # the file now names the new holder
        lock.release()
    finally:
        holder.kill()
        holder.wait(10)


# ---------------------------------------------------------------- bind_publisher


def test_the_events_socket_is_private_replaces_a_stale_file_and_publishes_by_key(tmp_path):
    path = tmp_path / events.EVENTS_SOCKET_NAME
    path.write_text("left by a worker that was killed")
    zctx = zmq.Context()
    old = os.umask(0o022)
    try:
        pub = bind_publisher(zctx, str(tmp_path))
        assert os.umask(0o022) == 0o022  # the process's umask is given back
        assert stat.S_ISSOCK(os.stat(path).st_mode) and mode(path) == 0o600
        sub = zctx.socket(zmq.SUB)
        sub.setsockopt(zmq.LINGER, 0)
        sub.setsockopt(zmq.SUBSCRIBE, b"d|fast|")
        sub.connect(events.endpoint(str(tmp_path)))
        wanted = events.data_key("fast", "array", "/a")

        def delivered():  # a SUB joins a moment after connect: publish until one arrives
            pub.send_multipart([events.data_key("slow", "array", "/a"), b"not subscribed"])
            pub.send_multipart([wanted, protocol.pack({"ts": 1}), b"{}"])
            return sub.poll(50) and sub.recv_multipart()

        frames = poll_until(delivered, 5, message="a frame through the events socket")
        assert frames == [wanted, protocol.pack({"ts": 1}), b"{}"]
        while sub.poll(100):
            assert sub.recv_multipart()[0] == wanted  # never the key it did not subscribe to
        sub.close()
        pub.close()
    finally:
        os.umask(old)
        zctx.term()


def test_the_events_socket_hands_over_every_subscription_even_a_repeated_one(tmp_path):
    """Verbose: the ROS worker confirms each subscription (ipc/events.py), so it must see each one."""
    zctx = zmq.Context()
    try:
        pub = bind_publisher(zctx, str(tmp_path))
        subs = []
        for _ in range(2):  # two HTTP workers watching the same trigger
            sub = zctx.socket(zmq.SUB)
            sub.setsockopt(zmq.LINGER, 0)
            sub.setsockopt(zmq.SUBSCRIBE, b"t|e|trig_1|")
            sub.connect(events.endpoint(str(tmp_path)))
            subs.append(sub)
        got = [pub.recv() if pub.poll(5000) else None for _ in range(2)]
        assert got == [b"\x01t|e|trig_1|"] * 2
        pub.send_multipart([b"t|e|trig_1|"])  # the confirmation: both have the subscription in place
        assert [s.recv_multipart() if s.poll(5000) else None for s in subs] == [[b"t|e|trig_1|"]] * 2
        for sub in subs:
            sub.close()
        pub.close()
    finally:
        zctx.term()


# ---------------------------------------------------------------- ControlServer


@pytest.fixture
def control(tmp_path):
    zctx = zmq.Context()
    stats = Stats(pool_cap=4, cold_wait_cap=2, watchdog_threshold_ms=100)
    server = ControlServer(zctx, str(tmp_path), stats, {"version": "9.9.9", "node": "/gw_sub"})
    server.start()
    client = RosWorkerClient.for_runtime_dir(str(tmp_path))
    yield server, stats, client
    client.close()
    server.finish()
    zctx.term()


def test_ping_and_stats_are_answered_from_the_counters(control, tmp_path):
    server, stats, client = control
    assert mode(tmp_path / protocol.CONTROL_SOCKET_NAME) == 0o600
    ping = client.call("ping", timeout=2)
    assert ping["version"] == "9.9.9" and ping["node"] == "/gw_sub"
    assert ping["pid"] == os.getpid() and ping["protocol"] == protocol.VERSION
    assert 0 <= ping["uptime_s"] < 60
    stats.pool_hits = 42
    answer = client.call("stats", timeout=2)
    assert answer["pid"] == os.getpid()
    assert answer["data_provider"]["pool_hits"] == 42  # read at the time of asking
    assert {k: v for k, v in answer.items() if k != "pid"} == stats.snapshot()


@pytest.fixture
def dealer(control):
    """A raw socket on the control endpoint: sends what the client never would."""
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(control[2].control_endpoint)
    yield sock
    sock.close()


def test_other_commands_are_refused_with_the_socket_to_send_them_to(dealer):
    def ask(message: dict) -> dict:
        dealer.send(protocol.pack(message))
        assert dealer.poll(2000), "no answer"
        return protocol.unpack(dealer.recv(), protocol.MAX_REPLY_FRAME)

    reply = ask({"v": protocol.VERSION, "id": 1, "cmd": "sample", "args": {"topic": "/a"}})
    assert reply["id"] == 1 and reply["ok"] is False
    assert reply["error"]["code"] == "bad-request" and protocol.SOCKET_NAME in reply["error"]["message"]
    reply = ask({"v": protocol.VERSION, "id": 2, "cmd": "rm -rf"})
    assert reply["error"]["code"] == "unknown-command"
    reply = ask({"v": protocol.VERSION + 1, "id": 3, "cmd": "ping"})
    assert reply["error"]["code"] == "unsupported-version"
    assert reply["error"]["params"] == {"supported": protocol.VERSION}
    reply = ask({"v": protocol.VERSION, "id": 4, "cmd": "ping", "deadline_ms": 0})
    assert reply["error"]["code"] == "bad-request"
    reply = ask({"v": protocol.VERSION, "id": 5, "cmd": "ping", "request_id": "has space"})
    assert reply["error"]["code"] == "bad-request"
    assert ask({"v": protocol.VERSION, "id": 6, "cmd": "ping"})["ok"] is True


def test_frames_that_are_not_requests_are_dropped_and_counted(control, dealer):
    _, stats, client = control
    dealer.send(b"\xc1 not msgpack")                       # undecodable
    dealer.send_multipart([b"two", b"frames"])              # not one frame
    dealer.send(protocol.pack({"v": protocol.VERSION, "id": "one", "cmd": "ping"}))  # no integer id
    poll_until(lambda: stats.ipc_dropped_frames == 3, 5, message="three frames dropped")
    assert not dealer.poll(200)                             # and none of them answered
    assert client.call("ping", timeout=2)["version"] == "9.9.9"


def test_the_control_thread_trips_the_watchdog_while_the_ros_thread_is_busy(control):
    _, stats, client = control
    stats.task_started()  # the ROS thread started a task and is stuck in it (threshold 100 ms)
    poll_until(lambda: stats.degraded, 5, message="degraded")
    answer = client.call("stats", timeout=2)["executor"]
    assert answer["degraded"] is True and answer["watchdog_trips"] == 1
    assert answer["current_task_age_ms"] >= 100


def test_finish_removes_the_socket_and_a_start_that_cannot_bind_raises(tmp_path):
    zctx = zmq.Context()
    try:
        stats = Stats(pool_cap=1, cold_wait_cap=1, watchdog_threshold_ms=100)
        server = ControlServer(zctx, str(tmp_path), stats, {})
        server.start()
        assert (tmp_path / protocol.CONTROL_SOCKET_NAME).exists()
        started = time.monotonic()
        server.finish()
        assert not server._thread.is_alive() and time.monotonic() - started < 3
        assert not (tmp_path / protocol.CONTROL_SOCKET_NAME).exists()
        nowhere = ControlServer(zctx, str(tmp_path / "missing"), stats, {})
        with pytest.raises(zmq.ZMQError):
            nowhere.start()
    finally:
        zctx.destroy(linger=0)  # (as rosworker/main.py does when it cannot serve)

