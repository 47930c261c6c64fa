"""What cyclic subscriptions may cost, through a real gateway: caps per client, and topics nobody publishes.

One client address holds at most ``max_subscriptions_per_client``; the
subscriptions of topics that do not exist (or have no publisher) cost the ROS
worker nothing per tick, and such a topic streams data as soon as a publisher
appears.  The restart state belongs to a ROS worker that died, not to a new
gateway.  Streaming itself is in tests/system/subscriptions/test_app_streams.py.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time

import pytest
import requests

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from tests.support.rospub import publisher, unique_topic
from tests.support.sse import EventStream


def _base(gw: Gateway) -> str:
    return f"{gw.api}/components/{gw.host()}/cyclic-subscriptions"


def _create(session, gw: Gateway, base: str, topic: str, interval: str = "normal", client: str | None = None,
            duration: int = 300) -> requests.Response:
    headers = {"X-Forwarded-For": client} if client else {}
    return session.post(base, headers=headers, timeout=15, json={
        "resource": f"/api/v1/components/{gw.host_id}/data{topic}", "interval": interval, "duration": duration})


def _gateway(*args: str, **kw) -> Gateway:
    gw = Gateway("--log-level", "warning", *args, **kw)
    gw.host_id = gw.host()
    return gw


def test_one_client_address_holds_at_most_its_cap_and_others_still_get_theirs():
    gw = _gateway("--max-subscriptions-per-client", "3")
    try:
        base, topic = _base(gw), unique_topic("capped")
        with requests.Session() as s:
            mine = [_create(s, gw, base, topic, client="10.1.0.1") for _ in range(3)]
            assert [r.status_code for r in mine] == [201] * 3, [r.text for r in mine]
            refused = _create(s, gw, base, topic, client="10.1.0.1")
            assert refused.status_code == 503, refused.text
            assert refused.headers["Retry-After"] == "5"
            doc = refused.json()
            assert doc["error_code"] == "service-unavailable"
            assert "max_subscriptions_per_client" in doc["message"] and "10.1.0.1" in doc["message"], doc
            assert doc["parameters"] == {"max_subscriptions_per_client": 3}, doc
            # another address (behind the trusted local proxy) still gets its own
            other = _create(s, gw, base, topic, client="10.1.0.2")
            assert other.status_code == 201, other.text
            # a deletion gives the first client room again
            assert s.delete(f"{base}/{mine[0].json()['id']}", timeout=15).status_code == 204
            assert _create(s, gw, base, topic, client="10.1.0.1").status_code == 201
    finally:
        gw.stop()


MADE_UP = 1000  # fast subscriptions (the default max_subscriptions), each on a topic nobody publishes


@pytest.mark.slow  # a 70 s load scenario: make reliability (see the Makefile)
def test_fast_subscriptions_on_made_up_topics_leave_the_ros_worker_nearly_idle(nodes):
    gw = _gateway()
    try:
        base = _base(gw)
        prefix = unique_topic("x")
        with requests.Session() as s:
            for i in range(MADE_UP):  # from several addresses: 100 each is the default cap per client
                r = _create(s, gw, base, f"{prefix}/made_up_{i}", "fast", client=f"10.2.0.{i // 100}")
                assert r.status_code == 201, r.text
        ros = gw.rosworker()
        ros.cpu_percent(None)
        time.sleep(3)  # a measurement window, not a wait for an event
        busy = ros.cpu_percent(None)
        print(f"ROS worker CPU with {MADE_UP} fast subscriptions on made-up topics: {busy:.1f} %")
        assert busy < 40, f"the ROS worker used {busy:.0f} % CPU for {MADE_UP} subscriptions on made-up topics"
        # the warm path still answers
        temp = unique_topic("temperature")
        nodes.append(publisher("costs_pub", temp, "sensor_msgs/msg/Temperature", {"temperature": 3.5}, rate=20))
        poll_until(lambda: gw.get(f"/components/{gw.host_id}/data{temp}").json()["x-medkit"]["status"] == "data",
                   30, message="a warm read")
        started = time.monotonic()
        assert gw.get(f"/components/{gw.host_id}/data{temp}", timeout=5).status_code == 200
        assert time.monotonic() - started < 2
    finally:
        gw.stop()


def test_a_made_up_topic_streams_data_once_a_publisher_appears(nodes):
    gw = _gateway()
    try:
        base, topic = _base(gw), unique_topic("later")
        with requests.Session() as s:
            r = _create(s, gw, base, topic, "fast")
        assert r.status_code == 201, r.text
        with EventStream(gw.port, r.json()["event_source"]) as stream:
            first = stream.next(timeout=10)
            assert first["payload"]["x-medkit"]["status"] == "metadata_only", first
            nodes.append(publisher("later_pub", topic, "sensor_msgs/msg/Temperature", {"temperature": 7.25},
                                   rate=20))
            data = poll_until(lambda: (lambda e: e if e and e.get("payload", {}).get("x-medkit", {}).get(
                "status") == "data" else None)(stream.next(timeout=10)), 30, interval=0,
                message="data frames once the topic has a publisher")
            assert data["payload"]["data"]["temperature"] == 7.25
    finally:
        gw.stop()


def test_a_new_gateway_on_the_same_runtime_dir_starts_without_the_last_runs_subscriptions():
    """The restart state is for a ROS worker that died (tests/system/subscriptions/test_app_streams.py: a SIGKILLed one keeps
    them), not for a gateway stopped and started again."""
    runtime_dir = tempfile.mkdtemp(prefix="sovd-gw-")
    try:
        gw = _gateway(runtime_dir=runtime_dir)
        try:
            base = _base(gw)
            r = _create(requests, gw, base, unique_topic("before"))
            assert r.status_code == 201, r.text
            state = os.path.join(runtime_dir, "restart-state.json")
            poll_until(lambda: os.path.exists(state) and r.json()["id"] in open(state).read(), 5,
                       message="the subscription saved")
        finally:
            assert gw.stop() == 0  # SIGTERM: a clean stop
        again = _gateway(runtime_dir=runtime_dir)
        try:
            assert requests.get(_base(again), timeout=15).json()["items"] == []
            assert requests.get(f"{_base(again)}/{r.json()['id']}", timeout=15).status_code == 404
        finally:
            again.stop()
    finally:
        shutil.rmtree(runtime_dir, ignore_errors=True)
