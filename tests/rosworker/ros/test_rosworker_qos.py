"""QoS matched to the publishers: latched values, best-effort and mixed publishers, rebuilds."""

from __future__ import annotations

import time
from types import SimpleNamespace

import orjson
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from common.harness.procs import poll_until
from rosworker.ros import qos
from tests.support.rospub import RosNode, publisher, unique_topic
from tests.support.rosworker import RosWorker


def endpoint(reliability, durability):
    return SimpleNamespace(qos_profile=QoSProfile(depth=10, reliability=reliability, durability=durability))


R, B = ReliabilityPolicy.RELIABLE, ReliabilityPolicy.BEST_EFFORT
V, T = DurabilityPolicy.VOLATILE, DurabilityPolicy.TRANSIENT_LOCAL


@pytest.mark.parametrize("publishers, reliability, durability", [
    ([(R, V)], R, V),
    ([(B, V)], B, V),
    ([(R, V), (B, V)], B, V),      # reliable only if every publisher is
    ([(R, T)], R, T),
    ([(R, V), (R, T)], R, T),      # transient local if any publisher is
    ([(B, T), (R, V)], B, T),
])
def test_match_qos_rules(publishers, reliability, durability):
    profile = qos.match_qos([endpoint(r, d) for r, d in publishers])
    assert (profile.reliability, profile.durability, profile.depth) == (reliability, durability, 1)


def test_latched_value_published_long_before_the_first_read_is_served(nodes):
    topic = unique_topic("state")
    nodes.append(publisher("latch", topic, "std_msgs/msg/String", {"data": "latched-value"},
                           once=True, durability="transient_local", depth=1))
    time.sleep(1.0)  # published well before anyone reads
    worker = RosWorker()
    try:
        reply = worker.sample_data(topic)
        assert orjson.loads(reply["data_json"]) == {"data": "latched-value"}
    finally:
        worker.stop()


def test_best_effort_publisher_is_heard(nodes):
    topic = unique_topic("be")
    nodes.append(publisher("be", topic, "std_msgs/msg/String", {"data": "best-effort"},
                           reliability="best_effort"))
    worker = RosWorker()
    try:
        assert orjson.loads(worker.sample_data(topic)["data_json"]) == {"data": "best-effort"}
    finally:
        worker.stop()


def test_best_effort_publisher_on_a_mixed_topic_is_heard(nodes):
    topic = unique_topic("mixed")
    # The reliable publisher stays silent; only the best-effort one speaks.
    nodes.append(RosNode({"node": "mixed", "publish": [
        {"topic": topic, "type": "std_msgs/msg/String", "rate": 0.001},
        {"topic": topic, "type": "std_msgs/msg/String", "rate": 20, "value": {"data": "from-be"},
         "reliability": "best_effort"}]}))
    worker = RosWorker()
    try:
        poll_until(lambda: next((t["publisher_count"] for t in worker.call("graph")["topics"]
                                 if t["name"] == topic), 0) == 2, 10, message="both publishers seen")
        assert orjson.loads(worker.sample_data(topic)["data_json"]) == {"data": "from-be"}
    finally:
        worker.stop()


def test_incompatible_publisher_joining_rebuilds_the_subscription(nodes):
    topic = unique_topic("rebuild")
    nodes.append(publisher("rel", topic, "std_msgs/msg/String", {"data": "reliable"}))
    worker = RosWorker(graph_poll_tick=50)
    try:
        assert orjson.loads(worker.sample_data(topic)["data_json"]) == {"data": "reliable"}
        # Our reader is Reliable now; a best-effort writer cannot match it until it is rebuilt.
        nodes.append(publisher("be_late", topic, "std_msgs/msg/String", {"data": "best-effort"},
                               reliability="best_effort", rate=20))
        poll_until(lambda: orjson.loads(worker.sample(topic)["data_json"]) == {"data": "best-effort"},
                   15, interval=0.02, message="the best-effort publisher heard")
        assert worker.stats()["details"]["evictions"]["qos_rebuild"] >= 1
        assert worker.stats()["data_provider"]["pool_size"] == 1
    finally:
        worker.stop()
