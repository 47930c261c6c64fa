"""Operations end to end: the real gateway calling real service and action servers in other processes.

Servers: ``tests/support/rosops.py`` (std_srvs Trigger, test_msgs BasicTypes and Arrays, the
test_msgs Fibonacci action).  The gateway runs two HTTP workers; the goals live in its ROS worker.
"""

from __future__ import annotations

import concurrent.futures
import json
import signal
import sys
import threading

import pytest
import requests

from common.harness.gateway import Gateway
from common.harness.procs import Proc, poll_until

TOKEN = "ops-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
CALL_TIMEOUT = 10
ARM = "/apps/calib"


class OpsNode(Proc):
    """``tests/support/rosops.py`` in its own process."""

    def __init__(self, spec: dict, timeout: float = 20.0):
        super().__init__([sys.executable, "-m", "tests.support.rosops", json.dumps(spec)],
                         name=f"rosops {spec.get('node')}")
        self.wait_line(lambda line: line == "READY", timeout)


ARM_SPEC = {"node": "calib", "namespace": "/arm",
            "services": [{"name": "calibrate", "type": "std_srvs/srv/Trigger"},
                         {"name": "echo", "type": "test_msgs/srv/BasicTypes"},
                         {"name": "arrays", "type": "test_msgs/srv/Arrays"}],
            "actions": [{"name": "fib", "type": "test_msgs/action/Fibonacci", "step": 0.05}]}


@pytest.fixture(scope="module")
def arm():
    node = OpsNode(ARM_SPEC)
    yield node
    node.stop()


@pytest.fixture(scope="module")
def gw(arm, gateway):
    gw = gateway("--allow-operations", "--api-token", TOKEN, "--service-call-timeout", str(CALL_TIMEOUT),
                 "--workers", "2", "--debug-commands")
    poll_until(lambda: gw.get(ARM + "/operations").status_code == 200
               and len(gw.get(ARM + "/operations").json()["items"]) == 4, 20, message="arm operations")
    return gw


def post(gw, path: str, body: dict, headers: dict | None = None, **kw) -> requests.Response:
    kw.setdefault("timeout", 30)
    return requests.post(gw.api + path, json=body, headers=AUTH if headers is None else headers, **kw)


def run_goal(gw, order: int) -> str:
    r = post(gw, ARM + "/operations/fib/executions", {"parameters": {"order": order}})
    assert r.status_code == 202, r.text
    assert r.headers["Location"] == f"/api/v1{ARM}/operations/fib/executions/{r.json()['id']}"
    assert r.json()["status"] == "running"
    return r.json()["id"]


def wait_done(gw, exec_id: str, timeout: float = 20) -> dict:
    def done():
        body = gw.get(f"{ARM}/operations/fib/executions/{exec_id}").json()
        return body if body["status"] in ("completed", "failed") else None
    return poll_until(done, timeout, message=f"goal {exec_id} finished")


# ---------------------------------------------------------------- listing and detail

def test_listing_names_services_and_actions_without_hidden_ones(gw):
    body = gw.get(ARM + "/operations").json()
    by_id = {item["id"]: item for item in body["items"]}
    assert sorted(by_id) == ["arrays", "calibrate", "echo", "fib"]
    assert body["x-medkit"]["total_count"] == 4
    calibrate = by_id["calibrate"]
    assert calibrate["name"] == "calibrate" and calibrate["asynchronous_execution"] is False
    assert calibrate["proximity_proof_required"] is False
    assert calibrate["x-medkit"]["ros2"] == {"service": "/arm/calibrate", "type": "std_srvs/srv/Trigger",
                                              "kind": "service"}
    assert calibrate["x-medkit"]["entity_id"] == "calib"
    assert calibrate["x-medkit"]["type_info"]["response"]["properties"]["success"]["type"] == "boolean"
    fib = by_id["fib"]
    assert fib["asynchronous_execution"] is True
    assert fib["x-medkit"]["ros2"] == {"action": "/arm/fib", "type": "test_msgs/action/Fibonacci",
                                        "kind": "action"}
    info = fib["x-medkit"]["type_info"]
    assert set(info) >= {"goal", "result", "feedback"}
    assert info["default_value"]["goal"] == {"order": 0}


def test_detail_and_basic_types_schema_with_non_finite(gw):
    r = gw.get(ARM + "/operations/echo")
    assert r.status_code == 200, r.text
    info = r.json()["item"]["x-medkit"]["type_info"]
    assert {"type": "string", "enum": ["NaN", "Infinity", "-Infinity"]} in \
        info["request"]["properties"]["float64_value"]["anyOf"]


def test_component_qualifies_nothing_when_names_are_unique(gw):
    host = gw.host()
    ids = {i["id"] for i in gw.get(f"/components/{host}/operations").json()["items"]}
    assert {"calibrate", "fib"} <= ids


def test_unknown_operation_and_execution(gw):
    r = gw.get(ARM + "/operations/nope")
    assert r.status_code == 404 and r.json()["error_code"] == "operation-not-found"
    r = gw.get(ARM + "/operations/fib/executions/" + "0" * 32)
    assert r.status_code == 404 and r.json()["error_code"] == "resource-not-found"
    r = gw.get("/apps/nobody/operations")
    assert r.status_code == 404 and r.json()["error_code"] == "entity-not-found"


# ---------------------------------------------------------------- services

def test_trigger_call(gw):
    r = post(gw, ARM + "/operations/calibrate/executions", {"parameters": {}})
    assert r.status_code == 200, r.text
    assert r.json()["parameters"]["success"] is True
    assert r.json()["parameters"]["message"].startswith("called ")
    assert gw.get(ARM + "/operations/calibrate/executions").json() == {"items": []}


def test_basic_types_round_trip_every_field_kind(gw):
    request = {"bool_value": True, "byte_value": 7, "char_value": 65, "float32_value": 1.5,
               "float64_value": "-Infinity", "int8_value": -8, "uint8_value": 255, "int16_value": -16000,
               "uint16_value": 65535, "int32_value": -2**31, "uint32_value": 2**32 - 1,
               "int64_value": -2**63, "uint64_value": 2**64 - 1, "string_value": "héllo"}
    r = post(gw, ARM + "/operations/echo/executions", {"request": request})
    assert r.status_code == 200, r.text
    assert r.json()["parameters"] == request


def test_arrays_round_trip(gw):
    r = post(gw, ARM + "/operations/arrays/executions",
             {"parameters": {"int32_values": [1, -2, 3], "string_values": ["a", "b", "c"],
                             "float64_values": [0.5, "NaN", 2.0]}})
    assert r.status_code == 200, r.text
    answer = r.json()["parameters"]
    assert answer["int32_values"] == [1, -2, 3] and answer["string_values"] == ["a", "b", "c"]
    assert answer["float64_values"] == [0.5, "NaN", 2.0]


def test_a_request_that_does_not_fit_names_the_field(gw):
    r = post(gw, ARM + "/operations/echo/executions", {"parameters": {"int8_value": 300}})
    assert r.status_code == 400
    assert r.json()["error_code"] == "invalid-parameter"
    assert "int8_value" in r.json()["message"]
    r = post(gw, ARM + "/operations/echo/executions", {"parameters": {"no_such_field": 1}})
    assert r.status_code == 400 and "no_such_field" in r.json()["message"]


def test_unknown_type_is_400_type_introspection_failed(gw):
    r = post(gw, ARM + "/operations/calibrate/executions", {"parameters": {}, "type": "nope_pkg/srv/Nope"})
    assert r.status_code == 400
    assert r.json()["vendor_code"] == "x-medkit-ros2-type-introspection-failed"


def test_writes_need_the_token(gw):
    r = post(gw, ARM + "/operations/calibrate/executions", {"parameters": {}}, headers={})
    assert r.status_code == 401
    r = post(gw, ARM + "/operations/calibrate/executions", {"parameters": {}},
             headers={"Authorization": "Bearer wrong"})
    assert r.status_code == 401   # a bad token: medkit's 401 invalid_token
    r = requests.delete(gw.api + ARM + "/operations/fib/executions/" + "0" * 32, timeout=10)
    assert r.status_code == 401


def test_fifty_concurrent_calls(gw):
    with concurrent.futures.ThreadPoolExecutor(50) as pool:
        answers = list(pool.map(lambda _: post(gw, ARM + "/operations/calibrate/executions", {}), range(50)))
    assert [a.status_code for a in answers] == [200] * 50
    messages = {a.json()["parameters"]["message"] for a in answers}
    assert len(messages) == 50   # every call reached the server and got its own answer


# ---------------------------------------------------------------- actions

def test_goal_feedback_and_result(gw):
    exec_id = run_goal(gw, 8)
    body = wait_done(gw, exec_id)
    assert body["status"] == "completed" and body["capability"] == "execute"
    assert body["x-medkit"]["ros2_status"] == "succeeded"
    assert body["x-medkit"]["goal_id"] == exec_id
    assert body["x-medkit"]["ros2"] == {"action": "/arm/fib", "type": "test_msgs/action/Fibonacci"}
    assert body["parameters"]["sequence"] == [0, 1, 1, 2, 3, 5, 8, 13, 21]
    ids = [i["id"] for i in gw.get(ARM + "/operations/fib/executions").json()["items"]]
    assert exec_id in ids


def test_feedback_is_readable_while_running(gw):
    exec_id = run_goal(gw, 60)
    seen = poll_until(lambda: (gw.get(f"{ARM}/operations/fib/executions/{exec_id}").json()
                               .get("x-medkit", {}).get("feedback")), 10, message="feedback")
    assert seen["sequence"][:3] == [0, 1, 1]
    r = requests.delete(f"{gw.api}{ARM}/operations/fib/executions/{exec_id}", headers=AUTH, timeout=30)
    assert r.status_code == 204, r.text
    body = wait_done(gw, exec_id)
    assert body["status"] == "failed" and body["x-medkit"]["ros2_status"] == "canceled"


def test_abort(gw):
    body = wait_done(gw, run_goal(gw, 13))
    assert body["status"] == "failed" and body["x-medkit"]["ros2_status"] == "aborted"


def test_stop_by_put_and_its_errors(gw):
    exec_id = run_goal(gw, 200)
    path = f"{gw.api}{ARM}/operations/fib/executions/{exec_id}"
    r = requests.put(path, json={"capability": "execute"}, headers=AUTH, timeout=30)
    assert r.status_code == 409 and r.json()["error_code"] == "precondition-not-fulfilled"
    r = requests.put(path, json={"capability": "freeze"}, headers=AUTH, timeout=30)
    assert r.status_code == 400 and r.json()["error_code"] == "invalid-parameter"
    r = requests.put(path, json={"capability": "stop"}, headers=AUTH, timeout=30)
    assert r.status_code == 202, r.text
    assert r.headers["Location"] == f"/api/v1{ARM}/operations/fib/executions/{exec_id}"
    body = wait_done(gw, exec_id)
    assert body["x-medkit"]["ros2_status"] == "canceled"
    r = requests.delete(path, headers=AUTH, timeout=30)
    assert r.status_code == 400 and r.json()["vendor_code"] == "x-medkit-ros2-action-rejected"
    assert r.json()["parameters"]["return_code"] == 3


def test_rejected_goal(gw):
    r = post(gw, ARM + "/operations/fib/executions", {"goal": {"order": -1}})
    assert r.status_code == 400
    assert r.json()["vendor_code"] == "x-medkit-ros2-action-rejected"


def test_twenty_concurrent_goals(gw):
    with concurrent.futures.ThreadPoolExecutor(20) as pool:
        ids = list(pool.map(lambda _: run_goal(gw, 5), range(20)))
    assert len(set(ids)) == 20
    for exec_id in ids:
        assert wait_done(gw, exec_id)["parameters"]["sequence"] == [0, 1, 1, 2, 3, 5]


def _sessions_on_two_workers(gw) -> tuple[requests.Session, requests.Session]:
    """Two keep-alive connections served by different HTTP workers."""
    first = requests.Session()
    pid = first.get(gw.api + "/x-sovd-debug/worker", timeout=10).json()["pid"]
    for _ in range(100):
        other = requests.Session()
        if other.get(gw.api + "/x-sovd-debug/worker", timeout=10).json()["pid"] != pid:
            return first, other
        other.close()
    raise AssertionError("every new connection landed on the same HTTP worker")


def test_an_execution_is_read_and_cancelled_through_the_other_http_worker(gw):
    one, other = _sessions_on_two_workers(gw)
    r = one.post(f"{gw.api}{ARM}/operations/fib/executions", json={"parameters": {"order": 300}},
                 headers=AUTH, timeout=30)
    assert r.status_code == 202, r.text
    path = gw.url + r.headers["Location"]
    r = other.get(path, timeout=10)
    assert r.status_code == 200 and r.json()["status"] == "running"
    assert r.json()["x-medkit"]["goal_id"] in [i["id"] for i in other.get(
        f"{gw.api}{ARM}/operations/fib/executions", timeout=10).json()["items"]]
    assert other.delete(path, headers=AUTH, timeout=30).status_code == 204
    assert wait_done(gw, r.json()["x-medkit"]["goal_id"])["x-medkit"]["ros2_status"] == "canceled"
    one.close()
    other.close()


def test_health_counts_operations(gw):
    before = gw.get("/health").json()["x-medkit-operations"]
    assert post(gw, ARM + "/operations/calibrate/executions", {}).status_code == 200
    wait_done(gw, run_goal(gw, 2))
    section = gw.get("/health").json()["x-medkit-operations"]
    assert section["operation_service_clients"] >= 1 and section["operation_action_clients"] >= 1
    assert section["operation_calls_total"] == before["operation_calls_total"] + 1
    assert section["operation_goals_total"] == before["operation_goals_total"] + 1
    assert section["operation_goals_tracked"] >= 1 and section["operation_calls_in_flight"] == 0
    metrics = requests.get(gw.url + "/metrics", timeout=10).text
    assert "sovd_ros_operation_calls_total" in metrics


def test_operations_are_off_by_default(arm):
    gateway = Gateway()
    try:
        poll_until(lambda: gateway.get(ARM + "/operations").status_code == 200, 20, message="listing")
        r = requests.post(gateway.api + ARM + "/operations/calibrate/executions", json={}, timeout=10)
        assert r.status_code == 403 and r.json()["error_code"] == "forbidden"
    finally:
        gateway.stop()


SLOW_SPEC = {"node": "slowcal", "namespace": "/slow",
             "services": [{"name": "calibrate", "type": "std_srvs/srv/Trigger", "delay": 4.0}]}


def test_a_call_cut_off_by_a_ros_worker_crash_is_504_outcome_unknown_not_retry():
    """The review's case: a 4 s service, the ROS worker SIGKILLed while it runs.  The service finishes,
    so the answer must not be 503 "retry shortly" (a client that obeys calibrates twice): it is 504
    not-responding, no Retry-After, the outcome unknown."""
    node = OpsNode(SLOW_SPEC)
    gw = None
    try:
        gw = Gateway("--allow-operations", "--service-call-timeout", "10", "--workers", "1")
        path = "/apps/slowcal/operations/calibrate/executions"
        poll_until(lambda: gw.get("/apps/slowcal/operations").status_code == 200, 20, message="slowcal operations")
        answers: list[requests.Response] = []
        caller = threading.Thread(target=lambda: answers.append(
            requests.post(gw.api + path, json={"parameters": {}}, timeout=30)))
        caller.start()
        node.wait_line(lambda line: line == "CALLING 1", 15)  # the request reached the server through the worker
        gw.rosworker().send_signal(signal.SIGKILL)
        caller.join(30)
        (r,) = answers
        assert r.status_code == 504, r.text
        assert "Retry-After" not in r.headers
        body = r.json()
        assert body["error_code"] == "not-responding" and "vendor_code" not in body
        assert "may or may not have been carried out" in body["message"]
        node.wait_line(lambda line: line == "CALLED 1", 15)  # and it was carried out
    finally:
        if gw is not None:
            gw.stop()
        node.stop()


def test_goal_survives_nothing_of_a_killed_ros_worker_but_reads_failed(gw):
    exec_id = run_goal(gw, 400)
    old = gw.rosworker_pid()
    gw.rosworker().send_signal(signal.SIGKILL)
    poll_until(lambda: gw.rosworker_pid() != old and gw.get("/health").json()
               ["x-medkit-subscription-executor"]["worker_alive"], 30, message="ROS worker restarted")
    r = poll_until(lambda: (lambda r: r if r.status_code == 200 else None)(
        gw.get(f"{ARM}/operations/fib/executions/{exec_id}")), 20, message="execution readable")
    body = r.json()
    assert body["status"] == "failed"
    assert body["x-medkit"]["ros2_status"] == "unknown"
    assert "restarted" in body["x-medkit"]["message"]
    r = requests.delete(f"{gw.api}{ARM}/operations/fib/executions/{exec_id}", headers=AUTH, timeout=30)
    assert r.status_code == 503 and r.json()["vendor_code"] == "x-medkit-ros2-action-unavailable"
    assert r.headers["Retry-After"]
    assert wait_done(gw, run_goal(gw, 3))["status"] == "completed"


class _Answer:
    """A ``requests`` answer seen as tests/app/openapi/answers.py's ``check`` reads a Flask one."""

    def __init__(self, response: requests.Response):
        self.status_code = response.status_code
        self.data = response.content
        self.headers = response.headers
        self.get_json = response.json


def test_answers_follow_the_openapi_document(gw):
    from app import openapi
    from tests.app.openapi.answers import check, part_operations
    from tests.app.operations.openapi_routes import elsewhere

    doc = openapi.document()
    seen: set[str] = set()
    host = gw.host()
    for collection, entity_id in (("apps", "calib"), ("components", host), ("functions", "arm")):
        base = f"/api/v1/{collection}/{entity_id}/operations"
        exec_id = run_goal(gw, 3) if collection == "apps" else None
        calls = [("GET", base, {}), ("GET", base + "/calibrate", {}), ("GET", base + "/nope", {}),
                 ("GET", base + "/fib/executions", {}), ("GET", base + "/calibrate/executions", {}),
                 ("POST", base + "/calibrate/executions", {"json": {}, "headers": AUTH}),
                 ("POST", base + "/calibrate/executions", {"json": {}}),
                 ("POST", base + "/echo/executions", {"json": {"parameters": {"int8_value": 1000}},
                                                      "headers": AUTH}),
                 ("POST", base + "/fib/executions", {"json": {"parameters": {"order": 2}}, "headers": AUTH}),
                 ("POST", base + "/fib/executions", {"json": {"parameters": {"order": -1}}, "headers": AUTH}),
                 ("GET", base + "/fib/executions/" + "f" * 32, {}),
                 ("PUT", base + "/fib/executions/" + "f" * 32, {"json": {"capability": "stop"},
                                                                  "headers": AUTH}),
                 ("DELETE", base + "/fib/executions/" + "f" * 32, {"headers": AUTH})]
        if exec_id:
            wait_done(gw, exec_id)
            calls += [("GET", f"{base}/fib/executions/{exec_id}", {}),
                      ("PUT", f"{base}/fib/executions/{exec_id}", {"json": {"capability": "reset"},
                                                                   "headers": AUTH})]
        for collection_ in ("components", "functions"):
            if collection == collection_:
                running = run_goal(gw, 500)
                calls += [("PUT", f"{base}/fib/executions/{running}", {"json": {"capability": "stop"},
                                                                       "headers": AUTH})]
                other = run_goal(gw, 500)
                calls += [("DELETE", f"{base}/fib/executions/{other}", {"headers": AUTH})]
        for method, path, kw in calls:
            r = requests.request(method, gw.url + path, timeout=30, **kw)
            seen.add(check(doc, method, path, _Answer(r)))
    documented = {op for op in part_operations("operations") if elsewhere(op)}  # the rest: tests/app/operations/
    assert documented == seen, f"not exercised: {documented - seen}"
