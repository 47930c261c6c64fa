"""The cyclic-subscription registry (rosworker/subscriptions/registry.py) and the frames the data family's
ticks publish for it (rosworker/data/ticks.py, the ``data`` sampler of the core's samplers).

In-process: a real ROS thread (``RosExecutor``'s loop, its timers), the real
graph monitor over a fake node, the real events channel (``core/events.py``) read by a real SUB
socket; the pool is a stand-in that says what a read of each topic answers and
counts what it is asked.  Through a real gateway and real publishers:
tests/system/subscriptions/test_app_streams.py, tests/system/subscriptions/test_app_subscription_expiry.py,
tests/system/subscriptions/test_app_subscription_costs.py.
"""

from __future__ import annotations

import json
import os
import time
from types import SimpleNamespace

import pytest
import zmq

from app.core.errors import ApiError
from common.harness.procs import poll_until
from ipc import events, protocol
from ipc.errors import IpcError
from rosworker.core.events import EventsChannel
from rosworker.core.graph import GraphMonitor
from rosworker.core.samplers import SamplerRegistry
from rosworker.data.ticks import TopicTicks
from rosworker.subscriptions.registry import StreamRegistry
from tests.support.rosunit import FakeNode, RosThread

TOPIC = "/engine/temperature"
TYPE = "std_msgs/msg/String"
RESOURCE = "/api/v1/apps/temp_sensor/data" + TOPIC


class FakePool:
    """What a read answers: ``messages`` (pooled, with a message), ``cold`` (pooled, none yet), ``errors``;
    any other topic has no publisher.  ``peeks`` and ``absents`` count what the registry asked."""

    def __init__(self):
        self.entries: dict[str, bool] = {}
        self.closing = False
        self.messages: dict[str, bytes] = {}
        self.cold: set[str] = set()
        self.errors: dict[str, IpcError] = {}
        self.peeks: list[str] = []
        self.absents: list[str] = []

    def check_graph(self, full: bool) -> None:
        pass

    def _meta(self, topic, reason, type_=None, pubs=0) -> dict:
        return {"topic": topic, "type": type_, "status": "metadata_only", "data_json": b"{}",
                "timestamp": 1, "publisher_count": pubs, "subscriber_count": 0, "reason": reason}

    def peek(self, topic: str, mode: str):
        self.peeks.append(topic)
        if topic in self.errors:
            raise self.errors[topic]
        if topic in self.messages:
            self.entries[topic] = True
            return {"topic": topic, "type": TYPE, "status": "data", "data_json": self.messages[topic],
                    "timestamp": 7, "publisher_count": 1, "subscriber_count": 0}
        if topic in self.cold:
            self.entries[topic] = True
            return None
        return self._meta(topic, "no-publishers")

    def absent(self, topic: str) -> dict:
        self.absents.append(topic)
        return self._meta(topic, "not-in-graph")

    def waiting(self, topic: str) -> dict:
        return self._meta(topic, "timeout", TYPE, 1)


def registry_of(ros: RosThread, pool, graph, save=None, sample_timeout: float = 0.3, here: bool = False,
                **limits):
    """The events channel, the ``data`` sampler over ``pool`` and the registry, as the core and the data
    and subscriptions families make them (on the ROS thread: the ticks set their timers; ``here``: on
    this thread, the ROS thread's loop not running)."""
    def make():
        events_ = EventsChannel(ros.zctx, ros.runtime_dir, ros.executor, ros.stats)
        samplers = SamplerRegistry()
        ticks = TopicTicks(SimpleNamespace(executor=ros.executor, events=events_, graph=graph, stats=ros.stats),
                           pool, sample_timeout)
        samplers.register("data", ticks)
        options = {"max_subscriptions": 100, "max_per_client": None, "max_duration": 3600, **limits}
        return events_, ticks, StreamRegistry(ros.executor, events_, samplers, ros.stats, save=save, **options)
    return make() if here else ros.call(make)


class Setup:
    """The registry as the families build it, its channel bound, with a SUB socket on its events."""

    def __init__(self, ros: RosThread, **limits):
        self.ros = ros
        self.node = FakeNode()
        self.pool = FakePool()
        self.stats = ros.stats
        self.graph = GraphMonitor(self.node, self.stats)
        self.graph.on_change(self.pool.check_graph)
        self.changes = 0

        def changed(then=None) -> None:  # the restart state's writer, written at once
            self.changes += 1
            if then is not None:
                then()

        self.events, self.ticks, self.registry = registry_of(ros, self.pool, self.graph, save=changed, **limits)
        ros.call(self.graph.tick)
        ros.call(self.events.bind)
        self.sub = ros.zctx.socket(zmq.SUB)
        self.sub.setsockopt(zmq.LINGER, 0)
        self.sub.setsockopt(zmq.SUBSCRIBE, b"")
        self.sub.connect(events.endpoint(ros.runtime_dir))
        self.next(events.HEARTBEAT_KEY)  # connected: the heartbeat comes every second

    def create(self, topic=TOPIC, interval="fast", duration=60, client="", entity="temp_sensor", mode="array"):
        return self.ros.call(self.registry.create, "apps", entity, RESOURCE, topic, mode, interval, duration,
                             client)

    def next(self, prefix: bytes, timeout: float = 5.0) -> list[bytes]:
        """The next message whose key starts with ``prefix`` (others are passed over)."""
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            if self.sub.poll(int(left * 1000) + 1):
                frames = self.sub.recv_multipart()
                if frames[0].startswith(prefix):
                    return frames
        raise AssertionError(f"no message {prefix!r} within {timeout} s")

    def frame(self, interval: str, topic: str, mode: str = "array") -> tuple[dict, bytes]:
        frames = self.next(events.data_key(interval, mode, topic))
        return protocol.unpack(frames[1]), frames[2]

    def control(self, sub_id: str, timeout: float = 5.0) -> dict:
        return protocol.unpack(self.next(events.CONTROL_KEY + sub_id.encode(), timeout)[1])

    def publisher_appears(self, topic: str = TOPIC) -> None:
        """A node publishing ``topic`` joins the graph, and the graph monitor polls."""
        self.node.add("/engine/temp_sensor", pub=[(topic, TYPE)])
        self.ros.call(self.graph.tick)

    def close(self) -> None:
        self.sub.close()
        self.ros.call(self.events.close)


@pytest.fixture
def streams(tmp_path):
    with RosThread(tmp_path) as ros:
        setup = Setup(ros)
        yield setup
        setup.close()


@pytest.fixture
def capped(tmp_path):
    with RosThread(tmp_path) as ros:
        setup = Setup(ros, max_subscriptions=3, max_per_client=2)
        yield setup
        setup.close()


# ---------------------------------------------------------------- the registry


def test_create_get_list_update_delete(streams):
    s = streams
    before = time.time_ns()
    a = s.create(duration=60, client="10.0.0.1")
    b = s.create(interval="slow", duration=30)
    assert a["id"].startswith("sub_") and a["id"] != b["id"]
    assert (a["collection"], a["entity_id"], a["resource"], a["topic"], a["bytes"], a["interval"], a["duration"],
            a["client"]) == ("apps", "temp_sensor", RESOURCE, TOPIC, "array", "fast", 60, "10.0.0.1")
    assert a["key"] == events.data_key("fast", "array", TOPIC)
    assert before + 59 * 10**9 < a["expires_at_ns"] <= time.time_ns() + 60 * 10**9
    assert s.ros.call(s.registry.get, "apps", "temp_sensor", a["id"]).wire()["id"] == a["id"]
    assert [x["id"] for x in s.ros.call(s.registry.listing, "apps", "temp_sensor")] == [a["id"], b["id"]]
    assert s.ros.call(s.registry.listing, "apps", "controller") == []
    for collection, entity in (("apps", "controller"), ("components", "temp_sensor")):
        with pytest.raises(IpcError) as info:  # another entity's subscription is not found
            s.ros.call(s.registry.get, collection, entity, a["id"])
        assert info.value.code == "no-such-subscription"
    assert (s.stats.active_subscriptions, s.stats.subscriptions_created, s.changes) == (2, 2, 2)
    assert sorted(json.loads(r)["id"] for r in s.ros.call(s.registry.records)) == sorted([a["id"], b["id"]])

    version = s.registry.version
    updated = s.ros.call(s.registry.update, "apps", "temp_sensor", a["id"], "normal", 10)
    assert updated["interval"] == "normal" and updated["duration"] == 10
    assert updated["key"] == events.data_key("normal", "array", TOPIC)
    event = s.control(a["id"])
    assert event["event"] == "updated" and event["key"] == updated["key"] and event["interval"] == "normal"
    assert 9 < event["expires_in"] <= 10
    assert s.registry.version > version and s.changes == 3
    assert (TOPIC, "array") in s.ticks.watches["normal"] and not s.ticks.watches["fast"]
    assert json.loads(s.ros.call(s.registry.records)[0])["interval"] == "normal"  # the restart record too

    s.ros.call(s.registry.delete, "apps", "temp_sensor", a["id"])
    assert s.control(a["id"])["event"] == "deleted"
    with pytest.raises(IpcError):
        s.ros.call(s.registry.delete, "apps", "temp_sensor", a["id"])
    assert [x["id"] for x in s.ros.call(s.registry.listing, "apps", "temp_sensor")] == [b["id"]]
    assert (s.stats.active_subscriptions, s.changes) == (1, 4)
    assert not s.ticks.watches["normal"]


def test_the_caps_in_all_and_per_client(capped):
    s = capped
    first = s.create(client="10.0.0.1")
    s.create(client="10.0.0.1")
    with pytest.raises(IpcError) as info:
        s.create(client="10.0.0.1")
    assert info.value.code == "subscriptions-full" and ApiError.from_ipc(info.value).status == 503
    assert info.value.params == {"max_subscriptions_per_client": 2} and "10.0.0.1" in info.value.message
    s.create(client="10.0.0.2")  # another client has room of its own
    with pytest.raises(IpcError) as info:
        s.create(client="10.0.0.3")
    assert info.value.params == {"max_subscriptions": 3}
    assert s.stats.max_subscriptions == 3 and s.stats.subscriptions_created == 3
    s.ros.call(s.registry.delete, "apps", "temp_sensor", first["id"])  # frees a slot in both
    s.create(client="10.0.0.1")
    assert s.registry.per_client == {"10.0.0.1": 2, "10.0.0.2": 1}


def test_expiry_runs_on_the_monotonic_clock_whatever_the_wall_clock_does(streams, monkeypatch):
    s = streams
    short = s.create(duration=1)
    long = s.create(duration=30)
    real = time.time_ns
    monkeypatch.setattr(time, "time_ns", lambda: real() - 3600 * 10**9)  # an hour back
    assert s.control(short["id"], timeout=5)["event"] == "expired"  # after 1 s, not 1 h + 1 s
    monkeypatch.setattr(time, "time_ns", lambda: real() + 7200 * 10**9)  # two hours ahead
    s.next(events.HEARTBEAT_KEY)  # the loop ran on: nothing else ended
    left = s.ros.call(s.registry.listing, "apps", "temp_sensor")
    assert [x["id"] for x in left] == [long["id"]]
    # expires_at_ns follows the wall clock, for display; the deadline does not move
    assert left[0]["expires_at_ns"] > real() + 7200 * 10**9
    assert (s.stats.subscriptions_expired, s.stats.active_subscriptions) == (1, 1)
    assert s.changes == 3


def test_the_saved_registry_is_restored_by_the_next_worker_without_what_expired(streams, tmp_path):
    s = streams
    a = s.create(duration=60, client="10.0.0.1")
    b = s.create(interval="slow", duration=600)
    saved = s.ros.call(s.registry.saved)
    gone = dict(saved[0], id="sub_gone", expires_at_ns=time.time_ns() - 1)
    junk = [dict(saved[0], id="sub_junk", unknown_field=1), dict(saved[0], id="sub_x", expires_at_ns="soon"),
            dict(saved[0], id="sub_y", interval="hourly")]
    (tmp_path / "next").mkdir()
    other = RosThread(tmp_path / "next")  # its loop is not started: restore() runs on this thread
    try:
        _, _, restored = registry_of(other, FakePool(), GraphMonitor(FakeNode(), other.stats), here=True)
        restored.restore([*saved, gone, *junk])
        assert sorted(restored.subs) == sorted([a["id"], b["id"]])
        wire = restored.subs[a["id"]].wire()
        assert {k: v for k, v in wire.items() if k != "expires_at_ns"} == \
            {k: v for k, v in a.items() if k != "expires_at_ns"}
        assert abs(wire["expires_at_ns"] - a["expires_at_ns"]) < 2 * 10**9
        assert restored.per_client == {"10.0.0.1": 1} and other.stats.active_subscriptions == 2
    finally:
        other.executor.close()
        other.zctx.destroy(linger=0)


# ---------------------------------------------------------------- the ticks


def test_a_pooled_topic_gets_one_frame_a_tick_however_many_subscriptions_watch_it(streams):
    s = streams
    s.publisher_appears()
    s.pool.messages[TOPIC] = b'{"data":"hot"}'
    s.create()
    s.create()
    meta, data = s.frame("fast", TOPIC)
    assert data == b'{"data":"hot"}'
    assert meta["status"] == "data" and meta["type"] == TYPE and meta["timestamp"] == 7
    assert isinstance(meta["ts"], int) and "data_json" not in meta
    for _ in range(3):
        s.frame("fast", TOPIC)
    peeks, ticks = s.ros.call(lambda: (s.pool.peeks.count(TOPIC), s.stats.ticks["fast"]))
    assert peeks == ticks >= 4  # one read a tick for both subscriptions
    assert s.stats.frames_published >= 4


def test_each_subscription_is_confirmed_and_what_is_sent_after_the_confirmation_arrives(streams):
    key = events.trigger_group_key("data", "array", "/confirmed")
    before = streams.stats.subscriptions_confirmed
    subs = []
    try:
        for _ in range(2):  # the second subscriber of a key is confirmed too (and the first again)
            sub = streams.ros.zctx.socket(zmq.SUB)
            sub.setsockopt(zmq.LINGER, 0)
            sub.setsockopt(zmq.SUBSCRIBE, key)
            sub.connect(events.endpoint(streams.ros.runtime_dir))
            subs.append(sub)
            assert sub.poll(5000), "no confirmation of the subscription"
            assert sub.recv_multipart() == [key]  # one frame: the subscribed prefix
        # Sent once, right after the confirmation: every confirmed subscriber has it.
        streams.ros.call(streams.events.send, [key, protocol.pack({"seq": 1}), b"{}"])
        for sub in subs:
            frames = None
            while sub.poll(5000):
                frames = sub.recv_multipart()
                if len(frames) > 1:
                    break
            assert frames == [key, protocol.pack({"seq": 1}), b"{}"]
        assert streams.stats.subscriptions_confirmed - before == 2
    finally:
        for sub in subs:
            sub.close()


def test_a_topic_nobody_publishes_is_answered_from_the_graph_without_asking_the_pool(streams):
    s = streams
    s.create(interval="fast")
    for _ in range(4):
        meta, data = s.frame("fast", TOPIC)
        assert meta["status"] == "metadata_only" and meta["reason"] == "not-in-graph" and data == b"{}"
        assert meta["timestamp"] == meta["ts"]  # a kept answer says "now"
    assert s.ros.call(lambda: (s.pool.absents.count(TOPIC), s.pool.peeks.count(TOPIC))) == (1, 0)
    # A publisher appears: the graph's next poll changes the generation, the next tick pools the topic.
    s.pool.messages[TOPIC] = b'{"data":"now"}'
    s.publisher_appears()
    poll_until(lambda: s.frame("fast", TOPIC)[1] == b'{"data":"now"}', 5, message="a data frame")
    assert s.pool.absents.count(TOPIC) == 1


def test_a_topic_without_its_first_message_gets_a_timeout_frame_after_the_sample_timeout(streams):
    s = streams
    s.publisher_appears()
    s.pool.cold.add(TOPIC)
    created = time.monotonic()
    s.create(interval="fast")
    meta, data = s.frame("fast", TOPIC)
    assert time.monotonic() - created >= 0.3  # nothing before sample_timeout
    assert meta["reason"] == "timeout" and meta["publisher_count"] == 1 and data == b"{}"


def test_a_read_that_fails_sends_the_error(streams):
    s = streams
    s.publisher_appears()
    s.pool.messages[TOPIC] = b"{}"
    s.pool.errors[TOPIC] = IpcError("message-undecodable", "the message does not decode", {"topic": TOPIC})
    s.create(interval="fast", mode="base64")
    meta, data = s.frame("fast", TOPIC, mode="base64")
    assert meta["error"]["code"] == "message-undecodable" and meta["error"]["params"] == {"topic": TOPIC}
    assert isinstance(meta["ts"], int) and data == b"{}"


def test_the_heartbeat_and_the_shutdown_event(streams):
    s = streams
    beat = protocol.unpack(s.next(events.HEARTBEAT_KEY)[1])
    assert beat["pid"] == os.getpid() and isinstance(beat["t"], int)
    s.ros.call(s.events.close)
    assert protocol.unpack(s.next(events.CONTROL_KEY + b"shutdown")[1]) == {"event": "shutdown"}
