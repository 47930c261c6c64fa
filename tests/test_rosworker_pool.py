"""The topic pool of the real ROS worker against real publishers in other processes."""

from __future__ import annotations

import os
import threading
import uuid

import pytest

from tests.support.procs import RosNode, poll_until, publisher
from tests.support.rosworker import SHADOW, RosWorker


def unique(name: str) -> str:
    return f"/t{uuid.uuid4().hex[:8]}/{name}"


@pytest.fixture
def nodes():
    started: list = []
    yield started
    for node in started:
        node.stop()


def test_first_read_subscribes_and_later_reads_come_from_the_pool(nodes):
    topic = unique("temperature")
    nodes.append(publisher("temp", topic, "sensor_msgs/msg/Temperature", {"temperature": 93.5},
                           counter="variance"))
    worker = RosWorker()
    try:
        first = worker.sample_data(topic)
        assert first["type"] == "sensor_msgs/msg/Temperature"
        assert first["publisher_count"] == 1
        stats = worker.stats()["data_provider"]
        assert stats["pool_size"] == 1
        hits_before = stats["pool_hits"]
        second = worker.sample(topic)
        assert second["status"] == "data"
        assert worker.stats()["data_provider"]["pool_hits"] == hits_before + 1
        assert worker.stats()["data_provider"]["pool_size"] == 1
        assert worker.call("pool")["topics"] == [topic]
        # Each queued command's count and time on the ROS thread (a warm sample's cost inside).
        before = worker.stats()["details"]["commands"]["sample"]
        for _ in range(10):
            assert worker.sample(topic)["status"] == "data"
        after = worker.stats()["details"]["commands"]["sample"]
        assert after["count"] == before["count"] + 10
        assert after["time_us"] > before["time_us"]
    finally:
        worker.stop()


def test_topic_without_publishers_answers_metadata_only_at_once():
    worker = RosWorker()
    try:
        reply = worker.sample(unique("nothing"), timeout_ms=20000)
        assert reply["status"] == "metadata_only"
        assert reply["reason"] == "not-in-graph"
        assert reply["data_json"] == b"{}"
        assert worker.stats()["data_provider"]["pool_size"] == 0
    finally:
        worker.stop()


def test_lru_promotion_order_evicts_the_least_recently_read(nodes):
    a, b, c = unique("a"), unique("b"), unique("c")
    nodes.append(RosNode({"node": "abc", "publish": [
        {"topic": t, "type": "std_msgs/msg/String", "rate": 20, "value": {"data": t}} for t in (a, b, c)]}))
    worker = RosWorker(max_pool_size=2)
    try:
        worker.sample_data(a)
        worker.sample_data(b)
        worker.sample_data(a)          # promotes a: b is now least recently used
        worker.sample_data(c)          # at the cap: evicts b
        assert worker.call("pool")["topics"] == [a, c]
        stats = worker.stats()
        assert stats["data_provider"]["evictions_total"] == 1
        assert stats["details"]["evictions"]["lru"] == 1
    finally:
        worker.stop()


def test_concurrent_first_reads_create_exactly_one_subscription(nodes):
    topic = unique("busy")
    nodes.append(publisher("busy", topic, "std_msgs/msg/String", {"data": "x"}, rate=50))
    worker = RosWorker(cold_wait_cap=0, max_queue_depth=4096)
    poll_until(lambda: worker.call("graph")["topics"], 10, message="publisher discovered")
    results: list = []
    errors: list = []

    def reader():
        try:
            for _ in range(50):
                results.append(worker.client.call("sample", {"topic": topic, "timeout_ms": 5000}, timeout=10))
        except Exception as exc:  # collected and asserted below
            errors.append(exc)

    threads = [threading.Thread(target=reader) for _ in range(16)]
    try:
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        assert not errors, errors[:3]
        assert len(results) == 16 * 50
        assert all(r["status"] == "data" for r in results)
        stats = worker.stats()["data_provider"]
        assert stats["pool_size"] == 1
        assert stats["pool_misses"] == 1
        assert stats["pool_hits"] == 16 * 50 - 1
    finally:
        worker.stop()


def test_publisher_leaving_evicts_the_entry_and_drops_our_subscription(nodes):
    topic = unique("leaving")
    pub = publisher("leaving", topic, "std_msgs/msg/String", {"data": "bye"})
    nodes.append(pub)
    worker = RosWorker(graph_poll_tick=50)
    try:
        worker.sample_data(topic)
        assert worker.stats()["data_provider"]["pool_size"] == 1
        pub.stop()
        poll_until(lambda: worker.stats()["data_provider"]["pool_size"] == 0, 10,
                   message="graph eviction")
        stats = worker.stats()
        assert stats["details"]["evictions"]["graph"] == 1
        # Our own subscription is gone: nothing is left on the topic.
        poll_until(lambda: not any(t["name"] == topic for t in worker.call("graph")["topics"]), 10,
                   message="topic gone from the graph")
        assert worker.sample(topic)["status"] == "metadata_only"
    finally:
        worker.stop()


def test_type_change_evicts_and_the_next_read_serves_the_new_type(nodes):
    topic = unique("morph")
    first = publisher("morph_a", topic, "std_msgs/msg/String", {"data": "text"})
    worker = RosWorker(graph_poll_tick=50)
    try:
        assert worker.sample_data(topic)["type"] == "std_msgs/msg/String"
        first.stop()
        nodes.append(publisher("morph_b", topic, "std_msgs/msg/Float64", {"data": 2.5}))
        reply = poll_until(lambda: (lambda r: r if r["type"] == "std_msgs/msg/Float64"
                                    and r["status"] == "data" else None)(worker.sample(topic)),
                           20, interval=0.1, message="new type served")
        assert reply["data_json"] == b'{"data":2.5}'
        assert worker.stats()["data_provider"]["type_change_events"] >= 1
    finally:
        worker.stop()


def test_idle_entries_are_swept(nodes):
    topic = unique("idle")
    nodes.append(publisher("idle", topic, "std_msgs/msg/String", {"data": "z"}))
    worker = RosWorker(idle_safety_net=1, idle_sweep_tick=0.2)
    try:
        worker.sample_data(topic)
        poll_until(lambda: worker.stats()["data_provider"]["pool_size"] == 0, 10, message="idle sweep")
        assert worker.stats()["details"]["evictions"]["idle"] == 1
    finally:
        worker.stop()


def test_manual_evict(nodes):
    topic = unique("manual")
    nodes.append(publisher("manual", topic, "std_msgs/msg/String", {"data": "m"}))
    worker = RosWorker()
    try:
        worker.sample_data(topic)
        assert worker.call("evict", {"topic": topic}) == {"topic": topic, "evicted": True}
        assert worker.call("evict", {"topic": topic}) == {"topic": topic, "evicted": False}
        assert worker.stats()["data_provider"]["pool_size"] == 0
    finally:
        worker.stop()


def test_unsupported_type_is_metadata_only_logged_once_and_counted(nodes):
    topic = unique("diag")
    nodes.append(publisher("diag", topic, "diagnostic_msgs/msg/KeyValue", {"key": "k", "value": "v"}))
    env = {"PYTHONPATH": os.pathsep.join(filter(None, [str(SHADOW), os.environ.get("PYTHONPATH")]))}
    worker = RosWorker(env=env)
    try:
        poll_until(lambda: worker.sample(topic)["reason"] == "unsupported-type", 15, interval=0.2,
                   message="unsupported type reported")
        for _ in range(3):
            reply = worker.sample(topic)
            assert reply["status"] == "metadata_only"
            assert reply["type"] is None or reply["type"] == "diagnostic_msgs/msg/KeyValue"
        assert worker.stats()["data_provider"]["unsupported_type_count"] == 1
        assert worker.stats()["data_provider"]["pool_size"] == 0
    finally:
        worker.stop()
    logged = [line for line in worker.output if "diagnostic_msgs/msg/KeyValue is not installed" in line]
    assert len(logged) == 1


def test_pooled_topics_are_subscribed_again_after_a_restart(nodes):
    topic = unique("rewarm")
    nodes.append(publisher("rewarm", topic, "std_msgs/msg/String", {"data": "warm"}))
    worker = RosWorker()
    runtime_dir = worker.runtime_dir
    try:
        worker.sample_data(topic)
        state = os.path.join(runtime_dir, "pool.json")
        poll_until(lambda: os.path.exists(state) and topic in open(state).read(), 5, message="pool saved")
        worker.signal(9)
        worker.proc.wait(10)
        again = RosWorker(runtime_dir=runtime_dir)
        try:
            poll_until(lambda: again.call("pool")["topics"] == [topic], 10, message="re-warmed pool")
        finally:
            again.stop()
    finally:
        worker.stop()


def test_eviction_wakes_the_waiters_of_the_entry(nodes):
    topic = unique("quiet")
    quiet = RosNode({"node": "quiet", "publish": [{"topic": topic, "type": "std_msgs/msg/String",
                                                   "rate": 0.001}]})
    nodes.append(quiet)
    worker = RosWorker(graph_poll_tick=50)
    try:
        poll_until(lambda: any(t["name"] == topic for t in worker.call("graph")["topics"]), 10,
                   message="quiet publisher discovered")
        answers: list = []
        waiter = threading.Thread(target=lambda: answers.append(worker.sample(topic, timeout_ms=20000)))
        waiter.start()
        poll_until(lambda: worker.stats()["data_provider"]["concurrent_cold_waits"] == 1, 5,
                   message="cold waiter")
        quiet.stop()  # the publisher leaves: the entry is evicted, its waiter woken long before 20 s
        waiter.join(15)
        assert answers and answers[0]["status"] == "metadata_only"
        assert answers[0]["reason"] == "evicted"
        assert worker.stats()["data_provider"]["concurrent_cold_waits"] == 0
    finally:
        worker.stop()
