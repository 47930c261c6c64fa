"""The ROS worker's single thread: cold-wait cap, watchdog, backpressure, shutdown, hostile IPC."""

from __future__ import annotations

import os
import threading
import time

import msgpack
import pytest
import zmq

from app.core.errors import ApiError
from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from ipc import protocol
from ipc.errors import IpcError
from tests.support.rospub import RosNode, publisher, unique_topic
from tests.support.rosworker import RosWorker


@pytest.fixture
def dealer():
    """``dealer(runtime_dir)``: a bare DEALER socket on that ROS worker's work socket, as a hand-made or hostile
    client has one; closed after the test."""
    ctx = zmq.Context()
    socks: list[zmq.Socket] = []

    def make(runtime_dir: str) -> zmq.Socket:
        sock = ctx.socket(zmq.DEALER)
        sock.setsockopt(zmq.LINGER, 0)
        sock.connect(protocol.endpoint(runtime_dir))
        socks.append(sock)
        return sock

    yield make
    for sock in socks:
        sock.close()
    ctx.term()


def silent(topics: list[str]) -> RosNode:
    """A node with publishers that exist in the graph but will not publish for a long time."""
    return RosNode({"node": "silent", "publish": [
        {"topic": t, "type": "std_msgs/msg/String", "rate": 0.001} for t in topics]})


def test_cold_wait_cap_sheds_excess_cold_callers_while_warm_topics_answer(nodes):
    cold = [unique_topic(f"cold{i}") for i in range(3)]
    warm = unique_topic("warm")
    nodes.append(silent(cold))
    nodes.append(publisher("warm", warm, "std_msgs/msg/String", {"data": "w"}, rate=20))
    with RosWorker(cold_wait_cap=2) as worker:
        worker.sample_data(warm)
        poll_until(lambda: sum(t["name"] in cold for t in worker.call("graph")["topics"]) == 3, 10,
                   message="silent publishers discovered")
        answers: list = []
        waiters = [threading.Thread(target=lambda t=t: answers.append(worker.sample(t, timeout_ms=4000)))
                   for t in cold[:2]]
        for t in waiters:
            t.start()
        poll_until(lambda: worker.stats()["data_provider"]["concurrent_cold_waits"] == 2, 5,
                   message="two cold waiters")
        started = time.monotonic()
        with pytest.raises(IpcError) as info:
            worker.sample(cold[2], timeout_ms=4000)
        shed_after = time.monotonic() - started
        assert info.value.code == "cold-wait-cap-exceeded"
        assert ApiError.from_ipc(info.value).status == 503
        assert info.value.params == {"topic": cold[2], "cold_wait_cap": 2}
        assert ApiError.from_ipc(info.value).retry_after
        assert shed_after < 2.0  # at once, not after the 4 s sample timeout
        assert worker.sample(warm)["status"] == "data"     # warm reads are unaffected
        assert worker.stats()["executor"]["worker_alive"]  # and so are stats
        for t in waiters:
            t.join(15)
        assert [a["reason"] for a in answers] == ["timeout", "timeout"]
        assert worker.stats()["data_provider"]["concurrent_cold_waits"] == 0


def test_watchdog_trips_once_per_episode_and_clears_when_idle():
    with RosWorker(watchdog_threshold=200, debug_commands=True) as worker:
        done = worker.busy(1.5)
        poll_until(lambda: worker.stats()["executor"]["degraded"], 5, message="degraded")
        busy = worker.stats()["executor"]   # readable while the ROS thread is stuck
        assert busy["watchdog_trips"] == 1
        assert busy["current_task_age_ms"] >= 200
        done.join(10)
        poll_until(lambda: not worker.stats()["executor"]["degraded"], 5, message="degraded cleared")
        after = worker.stats()["executor"]
        assert after["watchdog_trips"] == 1
        assert after["max_task_latency_us"] >= 1_400_000


def test_full_queue_answers_backpressure_at_once_and_counts_drops():
    with RosWorker(max_queue_depth=2, debug_commands=True) as worker:
        blocker = worker.busy(2)
        poll_until(lambda: worker.stats()["executor"]["current_task_age_ms"] > 0, 5, message="busy")
        outcomes: list = []

        def one():
            try:
                outcomes.append(worker.call("pool", timeout=10))
            except IpcError as exc:
                outcomes.append(exc)

        callers = [threading.Thread(target=one) for _ in range(6)]
        for t in callers:
            t.start()
        for t in callers:
            t.join(15)
        blocker.join(10)
        errors = [o for o in outcomes if isinstance(o, IpcError)]
        assert len(outcomes) == 6
        assert errors and all(e.code == "backpressure" and ApiError.from_ipc(e).status == 503 for e in errors)
        assert len(outcomes) - len(errors) == 2  # what fitted in the queue was served
        executor = worker.stats()["executor"]
        assert executor["queue_dropped"] == len(errors)
        assert executor["queue_max_depth_observed"] == 2


def test_shutdown_wakes_waiters_drains_and_exits_zero(nodes):
    topic = unique_topic("never")
    nodes.append(silent([topic]))
    worker = RosWorker()
    waiter, answers = worker.cold_waiter(topic)
    started = time.monotonic()
    worker.signal(15)
    code = worker.proc.wait(10)
    waiter.join(10)
    worker.stop()
    assert code == 0
    assert time.monotonic() - started < 10
    assert answers and answers[0]["status"] == "metadata_only"
    assert answers[0]["reason"] == "shutdown"


def test_every_waiter_hears_the_shutdown_answer_before_the_socket_closes(nodes):
    """Clients use ZMQ_IMMEDIATE, so an answer not yet read when the connection drops is lost:
    the worker keeps its socket open a moment after its last replies (ipc/server.py)."""
    topics = [unique_topic(f"never{i}") for i in range(4)]
    nodes.append(silent(topics))
    worker = RosWorker()
    poll_until(lambda: {t["name"] for t in worker.call("graph")["topics"]} >= set(topics), 10,
               message="silent publishers discovered")
    answers: list = []
    errors: list = []

    def wait(topic):
        try:
            answers.append(worker.sample(topic, timeout_ms=20000))
        except IpcError as exc:
            errors.append(exc)

    waiters = [threading.Thread(target=wait, args=(t,)) for t in topics]
    for w in waiters:
        w.start()
    poll_until(lambda: worker.stats()["data_provider"]["concurrent_cold_waits"] == len(topics), 5,
               message="cold waiters")
    worker.signal(15)
    assert worker.proc.wait(10) == 0
    for w in waiters:
        w.join(10)
    worker.stop()
    assert not errors, errors
    assert [a["reason"] for a in answers] == ["shutdown"] * len(topics)


def test_second_worker_on_the_same_runtime_dir_refuses_to_start():
    with RosWorker() as worker:
        second = RosWorker(runtime_dir=worker.runtime_dir, wait=False)
        assert second.proc.wait(30) == 3
        assert any("already serves" in line for line in second.output)
        assert worker.call("ping")["pid"] == worker.pid   # the socket was not stolen


def test_runtime_dir_and_socket_are_private():
    with RosWorker() as worker:
        assert os.stat(worker.runtime_dir).st_mode & 0o777 == 0o700
        sock = os.path.join(worker.runtime_dir, protocol.SOCKET_NAME)
        assert os.stat(sock).st_mode & 0o077 == 0


def test_hostile_ipc_frames_get_an_error_or_are_dropped_and_the_worker_keeps_serving(dealer):
    worker = RosWorker()
    sock = dealer(worker.runtime_dir)

    def ask(frames, expect_reply: bool):
        sock.send_multipart(frames)
        if sock.poll(2000 if expect_reply else 300):
            return protocol.unpack(sock.recv(), protocol.MAX_REPLY_FRAME)
        return None

    try:
        dropped = [
            [b"\x00\xff garbage"],
            [b""],
            [msgpack.packb([1, 2, 3])],
            [msgpack.packb({"v": 1, "cmd": "ping"})],            # no id
            [msgpack.packb({"v": 1, "id": "x", "cmd": "ping"})],  # id not an int
            [msgpack.packb({"v": 1, "id": 1, "cmd": "ping"})[:-3]],  # truncated
            [b"a", b"b", b"c"],                                  # extra frames
        ]
        for frames in dropped:
            assert ask(frames, expect_reply=False) is None
        answered = {
            "unsupported-version": {"v": 99, "id": 7, "cmd": "ping"},
            "unknown-command": {"v": 1, "id": 8, "cmd": "rm -rf", "args": {}},
            "bad-request": {"v": 1, "id": 9, "cmd": "sample", "args": [], "deadline_ms": 100},
            "invalid-topic": {"v": 1, "id": 10, "cmd": "sample", "args": {"topic": "../etc\x00"},
                              "deadline_ms": 1000},
        }
        for code, request in answered.items():
            reply = ask([msgpack.packb(request)], expect_reply=True)
            assert reply["id"] == request["id"] and reply["ok"] is False
            assert reply["error"]["code"] == code, reply
        bad_deadline = {"v": 1, "id": 11, "cmd": "pool", "args": {}, "deadline_ms": -5}
        assert ask([msgpack.packb(bad_deadline)], expect_reply=True)["error"]["code"] == "bad-request"
        for bad_id in ("", "x" * 129, "a b", "line\nbreak", 7, ["x"]):  # request_id: log-safe text only
            request = {"v": 1, "id": 12, "cmd": "pool", "args": {}, "deadline_ms": 1000, "request_id": bad_id}
            assert ask([msgpack.packb(request)], expect_reply=True)["error"]["code"] == "bad-request"
        good = {"v": 1, "id": 13, "cmd": "pool", "args": {}, "deadline_ms": 1000, "request_id": "a-Z_0.9"}
        assert ask([msgpack.packb(good)], expect_reply=True)["ok"] is True
        # An oversized frame: zmq drops the connection of a peer that sends one.
        big = dealer(worker.runtime_dir)
        big.send(b"\x00" * (protocol.MAX_FRAME + 10))
        big.close()
        assert worker.call("ping")["pid"] == worker.pid
        assert worker.stats()["details"]["ipc_dropped_frames"] >= 6
        assert worker.proc.poll() is None
    finally:
        worker.stop()


def test_ping_and_stats_are_refused_on_the_work_socket_and_answered_on_the_control_socket(dealer):
    """The control socket is their only home: no in-tree client sends them to the work socket."""
    worker = RosWorker()
    sock = dealer(worker.runtime_dir)
    try:
        for rid, cmd in enumerate(protocol.IMMEDIATE, 1):
            sock.send(msgpack.packb({"v": 1, "id": rid, "cmd": cmd, "args": {}, "deadline_ms": 1000}))
            assert sock.poll(5000), f"no answer to {cmd} on the work socket"
            reply = protocol.unpack(sock.recv(), protocol.MAX_REPLY_FRAME)
            assert reply["id"] == rid and reply["ok"] is False, reply
            assert reply["error"]["code"] == "bad-request", reply
            assert protocol.CONTROL_SOCKET_NAME in reply["error"]["message"]
        assert worker.call("ping")["pid"] == worker.pid  # the client sends them to the control socket
        assert "executor" in worker.stats()
    finally:
        worker.stop()


def test_ping_and_stats_never_wait_behind_a_queue_of_short_tasks(dealer):
    """120 tasks of 15 ms each once kept ``stats`` waiting 1.8 s: /health said the worker was dead.

    Here 400 tasks of 4 ms: each far below any take-over threshold, 1.6 s together."""
    gw = Gateway("--debug-commands", "--max-queue-depth", "1000", "--log-level", "warning")
    flood = dealer(gw.runtime_dir)
    client = gw.rosworker_client()
    try:
        for rid in range(400):
            flood.send(msgpack.packb({"v": 1, "id": rid, "cmd": "debug_sleep",
                                      "args": {"seconds": 0.004}, "deadline_ms": 60000}))
        poll_until(lambda: client.call("stats", timeout=5)["executor"]["queue_depth"] >= 200, 10,
                   message="the queue filled")
        started = time.monotonic()
        health = gw.get("/health").json()
        took = time.monotonic() - started
        assert health["x-medkit-subscription-executor"]["worker_alive"] is True
        assert health["x-medkit-subscription-executor"]["queue_depth"] > 0   # answered mid-queue
        assert took < 1.0, f"/health took {took:.3f} s behind the queue"
        started = time.monotonic()
        assert client.call("ping", timeout=0.5)["pid"] == gw.rosworker_pid()
        assert time.monotonic() - started < 0.5
        replies = set()
        while len(replies) < 400 and flood.poll(10000):
            replies.add(protocol.unpack(flood.recv(), protocol.MAX_REPLY_FRAME)["id"])
        assert replies == set(range(400))   # and every queued task was served
    finally:
        client.close()
        gw.stop()


class _Infos:
    """Stand-ins for rclpy's TopicEndpointInfo and its node: only what the pool reads."""

    def __init__(self, reliability):
        from rclpy.qos import QoSProfile

        self.node_name, self.node_namespace = "robot", "/"
        self.topic_type = "std_msgs/msg/String"
        self.qos_profile = QoSProfile(depth=1, reliability=reliability)


class _FailingNode:
    def __init__(self):
        self.infos = []
        self.created, self.destroyed = [], []
        self.fail = False

    def get_name(self):
        return "gw_sub"

    def get_namespace(self):
        return "/"

    def get_publishers_info_by_topic(self, topic):
        return list(self.infos)

    def get_subscriptions_info_by_topic(self, topic):
        return []

    def create_subscription(self, cls, topic, callback, profile):
        if self.fail:
            raise RuntimeError("rmw refused the subscription")
        sub = type("Sub", (), {"handle": type("H", (), {"get_publisher_count": lambda self: 1})()})()
        self.created.append(sub)
        return sub

    def destroy_subscription(self, sub):
        self.destroyed.append(sub)


def test_a_failed_qos_rebuild_keeps_the_old_subscription(tmp_path):
    """A unit test with a fake node: the new subscription is made before the old one goes."""
    from rclpy.qos import ReliabilityPolicy

    from rosworker.core.executor import RosExecutor
    from rosworker.core.stats import Stats
    from rosworker.data.pool import TopicPool

    stats = Stats(pool_cap=4, cold_wait_cap=4, watchdog_threshold_ms=5000)
    ctx = zmq.Context()
    executor = RosExecutor(ctx, str(tmp_path), stats, 16)
    node = _FailingNode()
    pool = TopicPool(node, executor, stats, max_pool_size=4, cold_wait_cap=4, idle_safety_net=0)
    try:
        node.infos = [_Infos(ReliabilityPolicy.RELIABLE)]
        assert pool.subscribe("/a")["status"] == "pooled"
        old = pool.entries["/a"].sub
        node.infos.append(_Infos(ReliabilityPolicy.BEST_EFFORT))  # the wanted QoS changes
        node.fail = True
        pool.check_graph(full=True)
        assert pool.entries["/a"].sub is old and old not in node.destroyed
        assert stats.loop_errors == 1                               # contained and counted
        node.fail = False
        pool.check_graph(full=True)                                 # the next check succeeds
        assert pool.entries["/a"].sub is not old and old in node.destroyed
        assert stats.evictions["qos_rebuild"] == 1
    finally:
        executor.close()
        ctx.term()


def test_a_poller_runs_when_its_entities_are_ready_or_its_time_is_due_and_a_failure_is_contained(tmp_path):
    """add_poller without a waiter (no rclpy here): polled every NO_WAITER_POLL s while it has entities
    open; at its due time when it has none; never while it has neither; a failing poll is counted."""
    from rosworker.core.executor import NO_WAITER_POLL, RosExecutor
    from rosworker.core.stats import Stats

    stats = Stats(pool_cap=4, cold_wait_cap=4, watchdog_threshold_ms=5000)
    ctx = zmq.Context()
    executor = RosExecutor(ctx, str(tmp_path), stats, 16)
    calls: list[float] = []
    idle_calls: list[float] = []
    due_calls: list[float] = []
    done = threading.Event()
    due_at = [None]

    def poll():
        calls.append(time.monotonic())
        if len(calls) == 3:
            raise RuntimeError("a failing poll is contained")
        if len(calls) >= 20:
            done.set()

    executor.add_poller("test", lambda: [] if done.is_set() else ["an entity"], poll)
    executor.add_poller("idle", lambda: [], lambda: idle_calls.append(1))
    executor.add_poller("timed", lambda: [], lambda: (due_calls.append(time.monotonic()), due_at.__setitem__(0, None)),
                        lambda: due_at[0])
    executor.bind()
    thread = threading.Thread(target=executor.run, daemon=True)
    started = time.monotonic()
    thread.start()
    try:
        assert done.wait(10), f"only {len(calls)} polls"
        # 20 polls paced by NO_WAITER_POLL, not by the 1 s idle wait (a generous bound that catches a hang)
        assert calls[19] - started < 20 * NO_WAITER_POLL + 5.0
        assert idle_calls == []
        assert stats.loop_errors == 1
        count = len(calls)
        time.sleep(0.05)
        assert len(calls) == count  # nothing open: not polled again
        wanted = time.monotonic() + 0.3
        executor.post(lambda: due_at.__setitem__(0, wanted))
        poll_until(lambda: due_calls, 5, message="the poll at its due time")
        assert due_calls[0] >= wanted and idle_calls == [] and len(calls) == count
    finally:
        executor.stop()
        thread.join(10)
        executor.close()
        ctx.term()
