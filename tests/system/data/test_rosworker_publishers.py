"""PUT through the real gateway to real subscribers: QoS matched to them, what the answer says,
idle expiry, and a PUT still waiting for its subscribers at shutdown."""

from __future__ import annotations

import signal
import threading

import pytest

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from tests.support.rospub import RosNode, unique_topic


@pytest.fixture
def gateway():
    started: list = []

    def start(*args: str) -> Gateway:
        gw = Gateway("--allow-publish", *args, "--log-level", "warning")
        started.append(gw)
        return gw

    yield start
    for gw in started:
        gw.stop()


def listener(topic: str, type_: str, **qos) -> RosNode:
    return RosNode({"node": "listener", "subscribe": [{"topic": topic, "type": type_, "echo": True,
                                                       **qos}]})


def subscribers_seen(gw, host: str, topic: str, count: int) -> bool:
    items = gw.get(f"/components/{host}/data").json()["items"]
    return any(i["id"] == topic for i in items) and \
        gw.get(f"/components/{host}/data{topic}").json()["x-medkit"]["subscriber_count"] >= count


def test_a_latched_command_input_hears_the_put_and_the_answer_counts_it(nodes, gateway):
    topic = unique_topic("lights_cmd")
    sub = listener(topic, "std_msgs/msg/Bool", durability="transient_local")
    nodes.append(sub)
    gw = gateway()
    host = gw.host()
    poll_until(lambda: subscribers_seen(gw, host, topic, 1), 15, message="the subscriber discovered")
    r = gw.put(f"/components/{host}/data{topic}", json={"type": "std_msgs/msg/Bool", "data": {"data": True}})
    assert r.status_code == 200, r.text
    ext = r.json()["x-medkit"]
    assert ext["status"] == "published"
    assert ext["subscriber_count"] == 1
    assert ext["unmatched_subscriber_count"] == 0
    assert "warning" not in ext
    poll_until(lambda: {"topic": topic, "data": {"data": True}} in sub.echoed(), 10,
               message="the transient-local subscriber heard the message")


def test_subscribers_the_message_cannot_reach_are_reported(nodes, gateway):
    topic = unique_topic("mixed")
    # A topic of two types takes either; the String subscriber can never match a Bool.
    nodes.append(listener(topic, "std_msgs/msg/Bool"))
    nodes.append(listener(topic, "std_msgs/msg/String"))
    gw = gateway("--publish-match-wait", "0.5")
    host = gw.host()
    poll_until(lambda: subscribers_seen(gw, host, topic, 2), 15, message="the subscribers discovered")
    r = gw.put(f"/components/{host}/data{topic}", json={"type": "std_msgs/msg/Bool", "data": {"data": True}})
    assert r.status_code == 200, r.text
    ext = r.json()["x-medkit"]
    assert ext["subscriber_count"] == 1
    assert ext["unmatched_subscriber_count"] == 1
    assert "did not receive" in ext["warning"]


def topic_types(client, topic: str) -> list[str]:
    """The topic's types in the ROS worker's graph: its own endpoints' types included."""
    return next((t["types"] for t in client.call("graph")["topics"] if t["name"] == topic), [])


def test_a_put_of_another_type_is_refused_and_creates_nothing(nodes, gateway):
    """Publishers only, subscribers only, both: a String PUT to a Bool topic is 400 and leaves no publisher."""
    bool_ = "std_msgs/msg/Bool"
    cases = {"publishers": ({"publish": [{"topic": "t", "type": bool_, "rate": 5, "value": {"data": True}}]}),
             "subscribers": ({"subscribe": [{"topic": "t", "type": bool_}]}),
             "both": ({"publish": [{"topic": "t", "type": bool_, "rate": 5, "value": {"data": True}}],
                       "subscribe": [{"topic": "t", "type": bool_}]})}
    topics = {}
    for kind, spec in cases.items():
        topic = topics[kind] = unique_topic(f"typed_{kind}")
        for item in spec.get("publish", []) + spec.get("subscribe", []):
            item["topic"] = topic
        nodes.append(RosNode({"node": f"typed_{kind}", **spec}))
    gw = gateway()
    host = gw.host()
    client = gw.rosworker_client()
    try:
        for kind, topic in topics.items():
            poll_until(lambda t=topic: topic_types(client, t) == [bool_], 15, message=f"{topic} discovered")
            r = gw.put(f"/components/{host}/data{topic}",
                       json={"type": "std_msgs/msg/String", "data": {"data": "on"}})
            assert r.status_code == 400, (kind, r.text)
            body = r.json()
            assert body["error_code"] == "invalid-parameter"
            assert "std_msgs/msg/String" in body["message"] and bool_ in body["message"], body
            assert body["parameters"]["topic_types"] == [bool_]
            assert body["parameters"]["type"] == "std_msgs/msg/String"
            # Nothing was created: the worker pools no publisher, and the graph (which lists the
            # gateway's own endpoints' types, registered locally when they are made) shows no String.
            assert client.call("stats")["details"]["publishers"] == 0, kind
            assert topic_types(client, topic) == [bool_], kind
        # The topic's own type is still published.
        r = gw.put(f"/components/{host}/data{topics['both']}", json={"type": bool_, "data": {"data": False}})
        assert r.status_code == 200, r.text
    finally:
        client.close()


def test_an_unused_publisher_expires(gateway):
    topic = unique_topic("once")
    gw = gateway("--idle-safety-net", "1", "--idle-sweep-tick", "0.1")
    host = gw.host()
    r = gw.put(f"/components/{host}/data{topic}", json={"type": "std_msgs/msg/Bool", "data": {"data": True}})
    assert r.status_code == 200, r.text
    client = gw.rosworker_client()
    try:
        poll_until(lambda: client.call("stats")["details"]["publishers_expired"] >= 1, 15,
                   message="the publisher expired")
        assert client.call("stats")["details"]["publishers"] == 0
        poll_until(lambda: all(t["name"] != topic for t in client.call("graph")["topics"]), 10,
                   message="the topic gone from the graph")
    finally:
        client.close()


def test_a_put_waiting_for_its_subscribers_at_shutdown_is_answered_not_published(nodes, gateway):
    topic = unique_topic("late")
    nodes.append(listener(topic, "std_msgs/msg/Bool"))
    nodes.append(listener(topic, "std_msgs/msg/String"))   # a Bool publisher waits for it in vain
    gw = gateway("--publish-match-wait", "20", "--ipc-timeout", "30")
    host = gw.host()
    poll_until(lambda: subscribers_seen(gw, host, topic, 2), 15, message="the subscribers discovered")
    answers: list = []
    put = threading.Thread(target=lambda: answers.append(gw.put(
        f"/components/{host}/data{topic}", json={"type": "std_msgs/msg/Bool", "data": {"data": True}},
        timeout=40)))
    put.start()
    client = gw.rosworker_client()
    try:
        poll_until(lambda: client.call("stats")["details"]["publishes_waiting"] == 1, 10,
                   message="the PUT waiting for its subscribers")
    finally:
        client.close()
    import os

    os.kill(gw.rosworker_pid(), signal.SIGTERM)
    put.join(20)
    assert answers, "the PUT got no answer"
    r = answers[0]
    assert r.status_code == 503, r.text
    body = r.json()
    assert body["vendor_code"] == "x-medkit-gateway-shutdown"
    assert "not published" in body["message"]
