"""The fork-safe IPC client against the real ROS worker: deadlines, dead workers, forks, pools, gevent."""

from __future__ import annotations

import json
import os
import sys
import threading
import time

import pytest

from app.core.errors import ApiError
from common.harness.procs import Proc, poll_until
from ipc import protocol
from ipc.client import POOL_SIZE, RosWorkerClient
from ipc.errors import IpcError
from tests.support.rosworker import RosWorker


@pytest.fixture
def worker():
    """A real ROS worker with the test-only commands (``debug_sleep``), stopped after the test."""
    worker = RosWorker(debug_commands=True)
    yield worker
    worker.stop()


@pytest.fixture
def client_of():
    """``client_of(worker, pool_size=None)``: a client of that worker (closed after the test, before the worker
    stops): the default pool, or one of ``pool_size`` channels."""
    made: list[RosWorkerClient] = []

    def make(worker: RosWorker, pool_size: int | None = None) -> RosWorkerClient:
        made.append(RosWorkerClient.for_runtime_dir(worker.runtime_dir) if pool_size is None
                    else RosWorkerClient(protocol.endpoint(worker.runtime_dir), pool_size=pool_size))
        return made[-1]

    yield make
    for client in made:
        client.close()


def test_a_request_lost_with_a_killed_worker_is_unavailable_at_once_not_a_timeout(worker, client_of):
    client = client_of(worker)
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
    assert exc.code == "unavailable" and ApiError.from_ipc(exc).status == 503
    assert waited < 10  # not the 20 s deadline


def test_no_worker_is_unavailable(tmp_path):
    client = RosWorkerClient.for_runtime_dir(str(tmp_path))
    try:
        with pytest.raises(IpcError) as info:
            client.call("ping", timeout=1)
        assert info.value.code == "unavailable"
    finally:
        client.close()


def test_a_silent_worker_is_a_deadline(worker, client_of):
    client = client_of(worker)
    threading.Thread(target=lambda: worker.client.call("debug_sleep", {"seconds": 3}, timeout=10),
                     daemon=True).start()
    time.sleep(0.3)
    with pytest.raises(IpcError) as info:
        client.call("pool", timeout=0.5)
    assert info.value.code == "deadline-exceeded" and ApiError.from_ipc(info.value).status == 504
    # The late reply to the timed-out call is dropped: the next call gets its own answer.
    time.sleep(3)
    assert client.call("pool", timeout=5) == {"topics": []}
    assert client.call("ping")["pid"] == worker.pid


def test_a_forked_child_makes_its_own_context(worker, client_of):
    client = client_of(worker)
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


def test_concurrent_callers_share_a_bounded_pool_of_channels(worker, client_of):
    client = client_of(worker, pool_size=4)
    answers: list = []

    def caller():
        for _ in range(5):
            answers.append(client.call("ping", timeout=10)["pid"])

    callers = [threading.Thread(target=caller) for _ in range(24)]
    for t in callers:
        t.start()
    for t in callers:
        t.join(30)
    assert not any(t.is_alive() for t in callers)
    assert answers == [worker.pid] * 120
    assert 1 <= client.channel_count <= 4


def test_a_caller_beyond_the_pool_waits_for_a_channel_within_its_deadline(worker, client_of):
    client = client_of(worker, pool_size=1)
    holder = threading.Thread(target=lambda: client.call("debug_sleep", {"seconds": 1.5}, timeout=10))
    holder.start()
    poll_until(lambda: worker.stats()["executor"]["current_task_age_ms"] > 0, 5,
               message="the only channel is busy")
    # (ping and stats have a pool of their own, on the control socket: use a work command.)
    with pytest.raises(IpcError) as info:
        client.call("pool", timeout=0.3)
    assert info.value.code == "deadline-exceeded" and "No free channel" in info.value.message
    assert "topics" in client.call("pool", timeout=10)  # once the channel is free again
    holder.join(10)
    assert client.channel_count == 1


GREEN_CALLER = r"""
import json, sys, time
from gevent import monkey
monkey.patch_all()
import gevent
from ipc import client as ipc_client
from ipc.errors import IpcError

client = ipc_client.RosWorkerClient.for_runtime_dir(sys.argv[1])
ticks = []

def tick():
    while True:
        ticks.append(time.monotonic())
        gevent.sleep(0.01)

ticker = gevent.spawn(tick)
# One greenlet waits 2 s for the ROS thread; 200 others ask for ping meanwhile.
slow = gevent.spawn(client.call, "debug_sleep", {"seconds": 2.0}, 10)
gevent.sleep(0.2)
pings = gevent.joinall([gevent.spawn(client.call, "ping", None, 10) for _ in range(200)], timeout=20)
slow.join(10)
gaps = [b - a for a, b in zip(ticks, ticks[1:])]
out = {"green": ipc_client.green(), "pings_ok": sum(1 for g in pings if g.successful()),
       "slow_ok": slow.successful(), "channels": client.channel_count,
       "per_endpoint": [pool.open_count for pool in client._pools.values()],
       "ticks": len(ticks), "max_gap_s": round(max(gaps), 3)}
print(json.dumps(out), flush=True)
# The disconnect monitor: a call whose worker dies is 'unavailable' at once.
def doomed():
    began = time.monotonic()
    try:
        client.call("debug_sleep", {"seconds": 30}, 20)
        return ("answered", 0)
    except IpcError as exc:
        return (exc.code, time.monotonic() - began)
g = gevent.spawn(doomed)
gevent.sleep(0.3)
print("SLEEPING", flush=True)
g.join(25)
print(json.dumps({"outcome": g.value}), flush=True)
ticker.kill()
client.close()
"""


def test_in_a_gevent_process_calls_are_green_pooled_and_never_block_the_loop():
    worker = RosWorker(debug_commands=True)
    proc = Proc([sys.executable, "-c", GREEN_CALLER, worker.runtime_dir], name="green caller")
    try:
        first = json.loads(proc.wait_line(lambda line: line.startswith('{"green"'), 60))
        assert first["green"] is True
        assert first["pings_ok"] == 200 and first["slow_ok"]
        # Bounded per endpoint (pings go to the control socket, the sleep to the work socket).
        assert len(first["per_endpoint"]) == 2 and all(1 <= n <= POOL_SIZE for n in first["per_endpoint"])
        assert first["channels"] == sum(first["per_endpoint"])
        # The loop kept running while calls waited: a ticker greenlet meant to tick every 10 ms
        # never missed a whole second (a call that blocked the loop would stop it for 2 s).
        assert first["ticks"] > 50 and first["max_gap_s"] < 1.0, first
        proc.wait_line(lambda line: line == "SLEEPING", 20)
        worker.signal(9)
        outcome = json.loads(proc.wait_line(lambda line: line.startswith('{"outcome"'), 30))["outcome"]
        assert outcome[0] == "unavailable" and outcome[1] < 10, outcome  # not the 20 s deadline
    finally:
        proc.stop()
        worker.stop()


@pytest.mark.parametrize("cmd", sorted(protocol.WRITES) + ["graph", "sample"])
def test_a_write_that_reached_a_worker_which_then_died_is_outcome_unknown_a_read_unavailable(tmp_path, cmd):
    """A bare ROUTER stands in for the ROS worker: it takes the request, then goes away unanswered.
    A write may have been carried out (504, no retry advice); a read is safe to retry (503)."""
    import zmq

    from ipc.server import bind_router

    zctx = zmq.Context()
    router = bind_router(zctx, str(tmp_path), protocol.SOCKET_NAME)
    received = threading.Event()

    def worker():
        if router.poll(10_000):
            router.recv_multipart()
            received.set()
        router.close(linger=0)  # dies with the request

    thread = threading.Thread(target=worker)
    thread.start()
    client = RosWorkerClient.for_runtime_dir(str(tmp_path))
    try:
        with pytest.raises(IpcError) as info:
            client.call(cmd, {}, timeout=15, connect_wait=5)
        assert received.is_set()
        answer = ApiError.from_ipc(info.value)
        if cmd in protocol.WRITES:
            assert info.value.code == "outcome-unknown", info.value
            assert answer.status == 504 and answer.error_code == "not-responding" and answer.retry_after is None
        else:
            assert info.value.code == "unavailable", info.value
            assert answer.status == 503 and answer.retry_after
    finally:
        client.close()
        thread.join(15)
        zctx.term()


def test_every_write_command_is_a_command_of_the_protocol():
    assert protocol.WRITES <= set(protocol.COMMANDS)
    assert not protocol.WRITES & {"graph", "sample", "stats", "ping", "fault_list", "param_list", "logs"}
