"""The ROS worker sleeps until something happens (issue 33), counted through ``loop_wakeups`` in /health.

Before, while a trigger, an open call or a cold reader existed, the ROS thread woke every 2 ms
(500 wake-ups a second).  Now a waiter thread sleeps in rcl's wait set over what has work open
and wakes the ROS thread when a message or a response comes: an open trigger on a quiet topic, a
call in flight, a reader waiting for a topic's first message add almost nothing to the idle rate,
and each still gets its answer.  The counts are read through a real gateway, from real ROS nodes
in other processes.
"""

from __future__ import annotations

import threading
import time

import pytest
import requests

from common.harness.procs import poll_until
from tests.support.linepub import LinePublisher
from tests.support.sse import EventStream
from tests.system.operations.test_operations import OpsNode

TOKEN = "wakeup-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
WINDOW = 3.0          # seconds each rate is counted over
MORE_THAN_IDLE = 4.0  # wake-ups a second something open may add to the idle rate (a 2 ms poll adds 500)
SLOW = {"node": "slowsvc", "namespace": "/wake",
        "services": [{"name": "work", "type": "std_srvs/srv/Trigger", "delay": 2.0},
                     {"name": "ping_a", "type": "std_srvs/srv/Trigger"},
                     {"name": "ping_b", "type": "std_srvs/srv/Trigger"}]}


@pytest.fixture(scope="module")
def gw(request, gateway):
    request.addfinalizer(OpsNode(SLOW).stop)   # the slow service's node, for the module
    gw = gateway("--workers", "1", "--api-token", TOKEN, "--allow-operations", "--service-call-timeout", "10",
                 "--sample-timeout", "8",
                 "--max-operation-clients", "1")  # two services called in turn: a client made and dropped each time
    poll_until(lambda: gw.get("/apps/slowsvc/operations").status_code == 200, 30, message="the slow service")
    return gw


@pytest.fixture
def pub(gw):
    name = f"wake_{time.monotonic_ns()}"
    made = LinePublisher(name, f"/{name}/value", "std_msgs/msg/Float64")
    made.app = name
    poll_until(lambda: gw.get(f"/apps/{name}").status_code == 200, 30, message=f"app {name}")
    yield made
    made.stop()


def wakeups(gw) -> int:
    return gw.get("/health", headers=AUTH).json()["x-medkit-subscription-executor"]["loop_wakeups"]


def rate(gw, during=None) -> float:
    """Wake-ups a second over ``WINDOW`` s (or while ``during()`` runs)."""
    first, started = wakeups(gw), time.monotonic()
    if during is None:
        time.sleep(WINDOW)
    else:
        during()
    return (wakeups(gw) - first) / (time.monotonic() - started)


def create_trigger(gw, pub) -> dict:
    r = requests.post(f"{gw.api}/apps/{pub.app}/triggers", headers=AUTH, timeout=10, json={
        "resource": f"/api/v1/apps/{pub.app}/data/{pub.app}/value",
        "trigger_condition": {"condition_type": "OnChange"}, "multishot": True})
    assert r.status_code == 201, r.text
    pub.wait_subscribers(1)
    return r.json()


def test_an_open_trigger_on_a_quiet_topic_adds_no_wakeups_and_a_message_still_fires_it(gw, pub):
    idle = rate(gw)
    trigger = create_trigger(gw, pub)
    stream = EventStream(gw.port, trigger["event_source"])
    try:
        assert stream.status == 200, stream.body
        with_trigger = rate(gw)
        assert with_trigger <= idle + MORE_THAN_IDLE, (idle, with_trigger)
        for value in (1.0, 2.0, 3.0):   # each message wakes the loop and fires the trigger
            pub.send({"data": value})
            event = stream.next(timeout=10)
            assert event is not None and event["payload"]["data"] == value, event
    finally:
        stream.close()
        requests.delete(f"{gw.api}/apps/{pub.app}/triggers/{trigger['id']}", headers=AUTH, timeout=10)


def test_a_call_in_flight_adds_no_wakeups_and_its_response_wakes_the_loop(gw):
    idle = rate(gw)
    answers: list[requests.Response] = []

    def call():
        answers.append(requests.post(f"{gw.api}/apps/slowsvc/operations/work/executions", headers=AUTH,
                                     json={"parameters": {}}, timeout=30))

    during = rate(gw, call)   # the 2 s service: the loop sleeps until its response comes
    assert answers and answers[0].status_code == 200, answers and answers[0].text
    assert answers[0].json()["parameters"]["success"] is True
    # the match of a new client is still looked at every 2 ms, for its first 0.25 s at most
    assert during <= idle + MORE_THAN_IDLE + 0.3 * 500 / 2.0, (idle, during)


def test_a_reader_waiting_for_a_first_message_is_answered_by_it_without_a_poll(gw, pub):
    idle = rate(gw)
    answers: list[requests.Response] = []
    reader = threading.Thread(target=lambda: answers.append(
        gw.get(f"/apps/{pub.app}/data/{pub.app}/value", timeout=30)))
    first = wakeups(gw)
    started = time.monotonic()
    reader.start()
    time.sleep(2.0)                       # the reader waits on the cold topic meanwhile
    pub.send({"data": 42.5})
    reader.join(30)
    waited = time.monotonic() - started
    assert answers and answers[0].status_code == 200, answers and answers[0].text
    assert answers[0].json()["data"]["data"] == 42.5
    assert (wakeups(gw) - first) / waited <= idle + MORE_THAN_IDLE, (idle, wakeups(gw) - first, waited)


def test_entities_made_and_destroyed_in_a_tight_loop_while_messages_flow(gw, pub):
    """Triggers, cyclic subscriptions and service clients made and dropped over and over (in and out of
    the waiter's wait set) while the topic flows: no crash, nothing contained, nothing left behind."""
    worker = gw.rosworker()
    threads = worker.num_threads()
    before = gw.get("/health", headers=AUTH).json()
    flowing = threading.Event()

    def flow():
        value = 0.0
        while not flowing.is_set():
            value += 1.0
            pub.send({"data": value})
            time.sleep(0.005)

    publisher = threading.Thread(target=flow, daemon=True)
    publisher.start()
    resource = f"/api/v1/apps/{pub.app}/data/{pub.app}/value"
    try:
        for i in range(25):
            trigger = requests.post(f"{gw.api}/apps/{pub.app}/triggers", headers=AUTH, timeout=10, json={
                "resource": resource, "trigger_condition": {"condition_type": "OnChange"}, "multishot": True})
            assert trigger.status_code == 201, trigger.text
            sub = requests.post(f"{gw.api}/apps/{pub.app}/cyclic-subscriptions", headers=AUTH, timeout=10,
                                json={"resource": resource, "interval": "fast", "duration": 30})
            assert sub.status_code == 201, sub.text
            call = requests.post(f"{gw.api}/apps/slowsvc/operations/ping_{'ab'[i % 2]}/executions", headers=AUTH,
                                 json={"parameters": {}}, timeout=30)
            assert call.status_code == 200, call.text
            assert requests.delete(f"{gw.api}/apps/{pub.app}/triggers/{trigger.json()['id']}", headers=AUTH,
                                   timeout=10).status_code == 204
            assert requests.delete(f"{gw.api}/apps/{pub.app}/cyclic-subscriptions/{sub.json()['id']}",
                                   headers=AUTH, timeout=10).status_code == 204
    finally:
        flowing.set()
        publisher.join(10)
    after = gw.get("/health", headers=AUTH).json()
    assert gw.rosworker().pid == worker.pid
    assert after["x-medkit-subscription-executor"]["loop_errors"] == before["x-medkit-subscription-executor"]["loop_errors"]
    assert after["x-medkit-streams"]["active_subscriptions"] == before["x-medkit-streams"]["active_subscriptions"]
    # the triggers' subscription went with the last trigger: the pool's is the only one left on the topic
    poll_until(lambda: pub.subscribers() <= 1, 20, message="the trigger subscription destroyed")
    assert worker.num_threads() == threads
