"""The topic pool of the real ROS worker against real publishers in other processes."""

from __future__ import annotations

import json
import os
import threading
import time

import pytest

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from common.settings import RESTART_ENV
from tests.support.rospub import RosNode, publisher, unique_topic
from tests.support.rosworker import SHADOW, RosWorker


def test_first_read_subscribes_and_later_reads_come_from_the_pool(nodes):
    topic = unique_topic("temperature")
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
        reply = worker.sample(unique_topic("nothing"), timeout_ms=20000)
        assert reply["status"] == "metadata_only"
        assert reply["reason"] == "not-in-graph"
        assert reply["data_json"] == b"{}"
        assert worker.stats()["data_provider"]["pool_size"] == 0
    finally:
        worker.stop()


def test_lru_promotion_order_evicts_the_least_recently_read(nodes):
    a, b, c = unique_topic("a"), unique_topic("b"), unique_topic("c")
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
    topic = unique_topic("busy")
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
    topic = unique_topic("leaving")
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
    topic = unique_topic("morph")
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
    topic = unique_topic("idle")
    nodes.append(publisher("idle", topic, "std_msgs/msg/String", {"data": "z"}))
    worker = RosWorker(idle_safety_net=1, idle_sweep_tick=0.2)
    try:
        worker.sample_data(topic)
        poll_until(lambda: worker.stats()["data_provider"]["pool_size"] == 0, 10, message="idle sweep")
        assert worker.stats()["details"]["evictions"]["idle"] == 1
    finally:
        worker.stop()


def test_manual_evict(nodes):
    topic = unique_topic("manual")
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
    topic = unique_topic("diag")
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
    topic = unique_topic("rewarm")
    nodes.append(publisher("rewarm", topic, "std_msgs/msg/String", {"data": "warm"}))
    worker = RosWorker()
    runtime_dir = worker.runtime_dir
    try:
        worker.sample_data(topic)
        state = os.path.join(runtime_dir, "restart-state.json")
        poll_until(lambda: os.path.exists(state) and topic in open(state).read(), 5, message="pool saved")
        worker.signal(9)
        worker.proc.wait(10)
        again = RosWorker(runtime_dir=runtime_dir, env={RESTART_ENV: "1"})  # as the supervisor restarts it
        try:
            poll_until(lambda: again.call("pool")["topics"] == [topic], 10, message="re-warmed pool")
        finally:
            again.stop()
    finally:
        worker.stop()


def test_eviction_wakes_the_waiters_of_the_entry(nodes):
    topic = unique_topic("quiet")
    quiet = RosNode({"node": "quiet", "publish": [{"topic": topic, "type": "std_msgs/msg/String",
                                                   "rate": 0.001}]})
    nodes.append(quiet)
    worker = RosWorker(graph_poll_tick=50)
    try:
        waiter, answers = worker.cold_waiter(topic)
        quiet.stop()  # the publisher leaves: the entry is evicted, its waiter woken long before 20 s
        waiter.join(15)
        assert answers and answers[0]["status"] == "metadata_only"
        assert answers[0]["reason"] == "evicted"
        assert worker.stats()["data_provider"]["concurrent_cold_waits"] == 0
    finally:
        worker.stop()


# ---- hardening: what one bad message, a busy pool or the gateway's own publisher must not do ----

# A std_msgs/String whose CDR says 1000 bytes follow, and then only "hi".
BAD_STRING_CDR = "00010000" + "e8030000" + "6869"


@pytest.fixture
def gateway():
    started: list = []

    def start(*args: str) -> Gateway:
        gw = Gateway(*args, "--log-level", "warning")
        started.append(gw)
        return gw

    yield start
    for gw in started:
        gw.stop()


def test_an_undecodable_message_answers_502_and_the_ros_worker_lives_on(nodes, gateway):
    bad, good = unique_topic("bad"), unique_topic("good")
    nodes.append(RosNode({"node": "garbler", "publish": [
        {"topic": bad, "type": "std_msgs/msg/String", "rate": 10, "raw": BAD_STRING_CDR}]}))
    nodes.append(publisher("fine", good, "std_msgs/msg/String", {"data": "ok"}))
    gw = gateway()
    host = gw.host()
    pid = gw.rosworker_pid()
    poll_until(lambda: gw.get(f"/components/{host}/data{good}").json()["x-medkit"]["status"] == "data",
               15, message="the good topic")

    def read_bad():
        r = gw.get(f"/components/{host}/data{bad}")
        if r.status_code == 200 and r.json()["x-medkit"].get("reason") in ("timeout", "no-publishers",
                                                                            "not-in-graph"):
            return None  # the garbler is not discovered (or matched) yet: ask again
        return [r]   # (a Response is falsy when its status is an error)

    [first] = poll_until(read_bad, 60, interval=0.2, message="the failing topic discovered")
    for r in [first] + [gw.get(f"/components/{host}/data{bad}") for _ in range(4)]:
        # the first read that reached a message, then warm reads of the same failing topic
        assert r.status_code == 502, r.text
        body = r.json()
        assert body["error_code"] == "vendor-error"
        assert body["vendor_code"] == "x-medkit-message-undecodable"
        assert body["parameters"]["topic"] == bad
        assert body["parameters"]["type"] == "std_msgs/msg/String"
        assert bad in body["message"]
    assert r.status_code == 502
    assert gw.rosworker_pid() == pid                      # never restarted
    assert gw.get(f"/components/{host}/data{good}").status_code == 200
    health = gw.get("/health").json()
    assert health["x-medkit-subscription-executor"]["worker_alive"] is True
    assert health["x-medkit-data-provider"]["undecodable_messages"] >= 1
    # The failing topic is not in the restart state: a restarted worker leaves it alone.
    # (Saved within 0.25 s of each change: the failing topic may be in a copy saved before its
    # first message failed, but never in one saved after.)
    state = os.path.join(gw.runtime_dir, "restart-state.json")
    saved = poll_until(lambda: (lambda t: t if good in t and bad not in t else None)(
        json.load(open(state))["topics"]), 5, message="restart state saved without the failing topic")
    assert good in saved and bad not in saved
    assert not any("Traceback" in line for line in gw.output)


def test_lru_eviction_never_cuts_a_cold_waiter_short(nodes, gateway):
    quiet, warm = unique_topic("quiet"), unique_topic("warm")
    nodes.append(RosNode({"node": "quiet", "publish": [{"topic": quiet, "type": "std_msgs/msg/String",
                                                        "rate": 0.001}]}))
    nodes.append(publisher("warm", warm, "std_msgs/msg/String", {"data": "w"}, rate=20))
    # The cold wait is the window in which the test looks: 8 s, so a loaded machine's slow /health
    # polls still see it.
    gw = gateway("--max-pool-size", "1", "--sample-timeout", "8")
    host = gw.host()
    poll_until(lambda: gw.get(f"/components/{host}/data{warm}").json()["x-medkit"]["status"] == "data",
               15, message="the warm topic")
    poll_until(lambda: gw.get(f"/components/{host}/data{quiet}", timeout=20).json()["x-medkit"].get("reason")
               == "timeout", 45, message="the quiet topic discovered (a read that times out)")
    answers: list = []
    waiter = threading.Thread(target=lambda: answers.append(gw.get(f"/components/{host}/data{quiet}")))
    waiter.start()
    poll_until(lambda: gw.get("/health").json()["x-medkit-data-provider"]["concurrent_cold_waits"] == 1,
               8, message="a cold waiter")
    # The pool is full (cap 1) with the waited-on entry: reading another topic must not evict it;
    # that read is told to come back (503 pool-busy) instead.
    busy = gw.get(f"/components/{host}/data{warm}")
    assert busy.status_code == 503, busy.text
    assert busy.json()["vendor_code"] == "x-medkit-pool-busy" and busy.headers["Retry-After"].isdigit()
    waiter.join(30)
    assert answers[0].json()["x-medkit"]["reason"] == "timeout"   # not "evicted"
    assert gw.get(f"/components/{host}/data{warm}").status_code == 200   # room again once it is over


def test_the_gateways_own_publisher_does_not_keep_a_topic_alive(nodes, gateway):
    topic = unique_topic("scan")
    robot = publisher("robot", topic, "std_msgs/msg/String", {"data": "from the robot"})
    nodes.append(robot)
    gw = gateway("--allow-publish")
    host = gw.host()
    url = f"/components/{host}/data{topic}"
    poll_until(lambda: gw.get(url).json()["x-medkit"]["status"] == "data", 15, message="robot data")
    r = gw.put(url, json={"type": "std_msgs/msg/String", "data": {"data": "from the gateway"}})
    assert r.status_code == 200, r.text
    robot.stop()
    gone = poll_until(lambda: (lambda b: b if b["x-medkit"]["status"] == "metadata_only" else None)(
        gw.get(url).json()), 15, message="the robot's publisher gone")
    assert gone["x-medkit"]["publisher_count"] == 0
    assert gone["x-medkit"]["reason"] in ("no-publishers", "evicted")
    # Only the gateway publishes there now: a read answers no-publishers at once.
    started = time.monotonic()
    again = gw.get(url).json()["x-medkit"]
    assert again["status"] == "metadata_only" and again["reason"] == "no-publishers"
    assert time.monotonic() - started < 0.9  # not the 1 s sample timeout


def test_the_byte_budget_bounds_the_pool_with_image_topics(nodes, gateway):
    topics = [unique_topic(f"camera{i}") for i in range(4)]
    image = {"height": 480, "width": 640, "encoding": "rgb8", "step": 1920,
             "data": {"__fill__": [7, 640 * 480 * 3]}}
    nodes.append(RosNode({"node": "cameras", "publish": [
        {"topic": t, "type": "sensor_msgs/msg/Image", "rate": 2, "value": image} for t in topics]},
        timeout=60))
    cap = 6 * 2**20   # room for one image with its JSON (~4.2 MB), not for four
    gw = gateway("--max-pool-bytes", str(cap), "--sample-timeout", "3")
    host = gw.host()
    for t in topics:
        poll_until(lambda t=t: gw.get(f"/components/{host}/data{t}").json()["x-medkit"]["status"] == "data",
                   20, message=f"image on {t}")
        provider = gw.get("/health").json()["x-medkit-data-provider"]
        assert provider["pool_bytes_cap"] == cap
        assert 0 < provider["pool_bytes"] <= cap
    client = gw.rosworker_client()
    try:
        details = client.call("stats")["details"]
    finally:
        client.close()
    assert details["evictions"]["bytes"] + details["pool_json_drops"] > 0
