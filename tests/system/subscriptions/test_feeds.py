"""Cyclic subscriptions on an execution and on a parameter, through the real gateway.

A real action server (``tests/support/rosops.py``) and a real parameter node
(``tests/support/paramnode.py``) in their own processes; the gateway's ROS
worker streams the goal's status and feedback and the parameter's value
(``rosworker/configurations/feed.py``), its HTTP workers frame them (``app/subscriptions/feeds.py``).
"""

from __future__ import annotations

import json
import sys
import time

import pytest
import requests

from common.harness.procs import Proc, poll_until

TOKEN = "feeds-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
ARM = "/apps/calib"
TUNER = "/apps/tuner"


class Node(Proc):
    def __init__(self, module: str, spec: dict, timeout: float = 20.0):
        super().__init__([sys.executable, "-m", module, json.dumps(spec)], name=f"{module} {spec['node']}")
        self.wait_line(lambda line: line == "READY", timeout)


@pytest.fixture(scope="module")
def nodes():
    started = [Node("tests.support.rosops", {
                   "node": "calib", "namespace": "/arm",
                   "services": [{"name": "calibrate", "type": "std_srvs/srv/Trigger"}],
                   "actions": [{"name": "fib", "type": "test_msgs/action/Fibonacci", "step": 0.1}]}),
               Node("tests.support.paramnode", {
                   "node": "tuner", "namespace": "/feeds",
                   "params": [{"name": "ratio", "value": 0.5, "float_range": [0.0, 1.0, 0.0]}]})]
    yield started
    for node in started:
        node.stop()


@pytest.fixture(scope="module")
def gw(nodes, gateway):
    gw = gateway("--allow-operations", "--allow-configurations", "--api-token", TOKEN, "--workers", "2",
                 "--log-level", "warning")
    poll_until(lambda: gw.get(ARM + "/operations").status_code == 200
               and len(gw.get(ARM + "/operations").json()["items"]) == 2
               and gw.get(TUNER).status_code == 200, 60, message="the action server and the parameter node")
    return gw


def subscribe(gw, entity: str, resource: str, interval: str = "fast", duration: int = 60) -> requests.Response:
    return requests.post(f"{gw.api}{entity}/cyclic-subscriptions", headers=AUTH, timeout=30,
                         json={"resource": resource, "interval": interval, "duration": duration})


def frames(stream: requests.Response):
    """The SSE events of an open stream, parsed, until the server ends it."""
    for line in stream.iter_lines():
        if line.startswith(b"data: "):
            yield json.loads(line[len(b"data: "):])


def run_goal(gw, order: int) -> str:
    r = requests.post(f"{gw.api}{ARM}/operations/fib/executions", json={"parameters": {"order": order}},
                      headers=AUTH, timeout=30)
    assert r.status_code == 202, r.text
    return r.json()["id"]


def test_an_execution_streams_feedback_then_ends_with_the_result(gw):
    exec_id = run_goal(gw, 30)  # 30 steps of 0.1 s: running while the stream opens, even on a loaded machine
    resource = f"/api/v1{ARM}/operations/fib/executions/{exec_id}"
    r = subscribe(gw, ARM, resource)
    assert r.status_code == 201, r.text
    sub = r.json()
    assert sub["observed_resource"] == resource and sub["interval"] == "fast"
    started = time.monotonic()
    with requests.get(gw.url + sub["event_source"], stream=True, timeout=30) as stream:
        assert stream.status_code == 200 and stream.headers["Content-Type"].startswith("text/event-stream")
        got = list(frames(stream))  # ends by itself: the goal's end closes the stream
    assert time.monotonic() - started < 20
    assert got and all(set(f) == {"timestamp", "payload"} for f in got), got
    running = [f["payload"] for f in got if f["payload"]["status"] == "running"]
    assert any("feedback" in p["x-medkit"] for p in running), got
    sequences = [p["x-medkit"]["feedback"]["sequence"] for p in running if "feedback" in p["x-medkit"]]
    assert sequences == sorted(sequences, key=len)  # feedback grows as the goal runs
    last = got[-1]["payload"]
    assert last["status"] == "completed" and last["x-medkit"]["ros2_status"] == "succeeded"
    assert last["x-medkit"]["goal_id"] == exec_id
    sequence = [0, 1]
    while len(sequence) < 31:  # the server's answer to order 30
        sequence.append(sequence[-1] + sequence[-2])
    assert last["parameters"] == last["x-medkit"]["result"] == {"sequence": sequence}
    assert last == gw.get(f"{ARM}/operations/fib/executions/{exec_id}").json()  # what a GET answers
    # ... and the subscription itself ends shortly after.
    location = r.headers["Location"]
    poll_until(lambda: requests.get(gw.url + location, timeout=10).status_code == 404, 20,
               message="the finished execution's subscription ended")


def test_a_stream_opened_after_the_goal_finished_gets_the_result_and_ends(gw):
    exec_id = run_goal(gw, 2)
    poll_until(lambda: gw.get(f"{ARM}/operations/fib/executions/{exec_id}").json()["status"] == "completed", 20,
               message="the goal finished")
    r = subscribe(gw, ARM, f"/api/v1{ARM}/operations/fib/executions/{exec_id}", interval="slow")
    assert r.status_code == 201, r.text
    with requests.get(gw.url + r.json()["event_source"], stream=True, timeout=30) as stream:
        got = list(frames(stream))
    assert len(got) == 1, got
    assert got[0]["payload"]["parameters"] == {"sequence": [0, 1, 1]}


def test_a_parameter_change_made_elsewhere_appears_in_the_stream(gw):
    resource = f"/api/v1{TUNER}/configurations/ratio"
    r = subscribe(gw, TUNER, resource)
    assert r.status_code == 201, r.text
    sub = r.json()
    seen = []
    try:
        with requests.get(gw.url + sub["event_source"], stream=True, timeout=30) as stream:
            events = frames(stream)
            first = next(events)
            assert set(first) == {"timestamp", "payload"}
            assert first["payload"] == gw.get(f"{TUNER}/configurations/ratio").json()
            assert first["payload"]["data"] == 0.5
            setter = Proc([sys.executable, "-m", "tests.support.paramnode", "--set", "/feeds/tuner", "ratio",
                           "0.75"], name="setter")
            try:
                assert setter.wait_line(lambda line: line.startswith("SET"), 20) == "SET ok"
            finally:
                setter.stop()
            deadline = time.monotonic() + 20
            for event in events:
                seen.append(event["payload"]["data"])
                if seen[-1] == 0.75 or time.monotonic() > deadline:
                    break
            assert seen[-1] == 0.75, seen
            assert event["payload"]["x-medkit"]["parameter"]["type"] == "double"
            assert event["payload"]["x-medkit"]["ros2"] == {"node": "/feeds/tuner"}
    finally:
        requests.delete(gw.url + r.headers["Location"], headers=AUTH, timeout=10)
        requests.put(f"{gw.api}{TUNER}/configurations/ratio", json={"data": 0.5}, headers=AUTH, timeout=10)


def test_a_deleted_parameter_subscription_ends_its_stream(gw):
    r = subscribe(gw, TUNER, f"/api/v1{TUNER}/configurations/ratio", interval="normal")
    assert r.status_code == 201, r.text
    with requests.get(gw.url + r.json()["event_source"], stream=True, timeout=30) as stream:
        events = frames(stream)
        assert next(events)["payload"]["id"] == "ratio"
        assert requests.delete(gw.url + r.headers["Location"], headers=AUTH, timeout=10).status_code == 204
        rest = list(events)  # ends: the loop would otherwise hang until the read timeout
    assert len(rest) <= 2


@pytest.mark.parametrize("entity,resource,status,code", [
    (ARM, f"/api/v1{ARM}/operations/fib/executions/{'0' * 32}", 404, "resource-not-found"),
    (ARM, f"/api/v1{ARM}/operations/nope/executions/{'0' * 32}", 404, "operation-not-found"),
    (ARM, f"/api/v1{ARM}/operations/calibrate/executions/{'0' * 32}", 404, "resource-not-found"),
    (ARM, f"/api/v1{ARM}/operations/fib", 400, "x-medkit-invalid-resource-uri"),
    (ARM, f"/api/v1{ARM}/operations/fib/executions/a/b", 400, "x-medkit-invalid-resource-uri"),
    (TUNER, f"/api/v1{TUNER}/configurations/nope", 404, "resource-not-found"),
    (TUNER, f"/api/v1{TUNER}/configurations", 400, "x-medkit-invalid-resource-uri"),
    (TUNER, f"/api/v1{ARM}/configurations/ratio", 400, "x-medkit-entity-mismatch"),
])
def test_bad_resources_are_refused(gw, entity, resource, status, code):
    r = subscribe(gw, entity, resource)
    assert r.status_code == status, r.text
    body = r.json()
    assert code in (body["error_code"], body.get("vendor_code")), body
    items = requests.get(f"{gw.api}{entity}/cyclic-subscriptions", timeout=10).json()["items"]
    assert resource not in [item["observed_resource"] for item in items]


def test_subscribing_needs_the_token(gw):
    r = requests.post(f"{gw.api}{TUNER}/cyclic-subscriptions", timeout=10,
                      json={"resource": f"/api/v1{TUNER}/configurations/ratio", "interval": "fast", "duration": 5})
    assert r.status_code == 401, r.text
