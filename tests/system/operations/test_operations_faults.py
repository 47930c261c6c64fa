"""Operations when things go wrong: a server that never answers, a server that leaves mid-goal,
ids that name more than one operation, no server at all, and hostile bodies (hypothesis).

Real gateway, real servers in other processes (``tests/support/rosops.py``).
"""

from __future__ import annotations

import concurrent.futures
import json
import time

import pytest
import requests
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from common.harness.procs import poll_until
from tests.system.operations.test_operations import OpsNode

TOKEN = "faults-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
CALL_TIMEOUT = 2
TRIGGER = "std_srvs/srv/Trigger"
FIB = "test_msgs/action/Fibonacci"


@pytest.fixture(scope="module")
def servers():
    nodes = [
        OpsNode({"node": "hung", "namespace": "/stuck", "spin": False,
                 "services": [{"name": "calibrate", "type": TRIGGER}],
                 "actions": [{"name": "fib", "type": FIB}]}),
        OpsNode({"node": "a", "namespace": "/dup", "services": [{"name": "reset", "type": TRIGGER}]}),
        OpsNode({"node": "b", "namespace": "/dup", "services": [{"name": "/dup/b_ns/reset", "type": TRIGGER}]}),
        OpsNode({"node": "c", "namespace": "/twice",
                 "services": [{"name": "reset", "type": TRIGGER}, {"name": "sub/reset", "type": TRIGGER}]}),
    ]
    yield nodes
    for node in nodes:
        node.stop()


@pytest.fixture(scope="module")
def gw(servers, gateway):
    gw = gateway("--allow-operations", "--api-token", TOKEN, "--service-call-timeout", str(CALL_TIMEOUT))
    poll_until(lambda: len(gw.get("/functions/dup/operations").json().get("items", [])) == 2
               and len(gw.get("/apps/hung/operations").json().get("items", [])) == 2
               and len(gw.get("/apps/c/operations").json().get("items", [])) == 2, 20,
               message="operations discovered")
    return gw


def post(gw, path: str, body, **kw) -> requests.Response:
    kw.setdefault("timeout", 30)
    return requests.post(gw.api + path, json=body, headers=AUTH, **kw)


def test_a_server_that_never_answers_is_504_and_the_gateway_stays_fast(gw):
    gw.get("/apps/hung/operations")  # warm
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        started = time.monotonic()
        call = pool.submit(post, gw, "/apps/hung/operations/calibrate/executions", {})
        goal = pool.submit(post, gw, "/apps/hung/operations/fib/executions", {"parameters": {"order": 3}})
        slowest = 0.0
        while not (call.done() and goal.done()):
            t0 = time.monotonic()
            assert gw.get("/health").status_code == 200
            assert gw.get("/apps/hung/operations").status_code == 200
            slowest = max(slowest, time.monotonic() - t0)
            if time.monotonic() - started > CALL_TIMEOUT + 10:
                break
        took = time.monotonic() - started
    for answer in (call.result(), goal.result()):
        assert answer.status_code == 504, answer.text
        assert answer.json()["error_code"] == "not-responding"
    assert took < CALL_TIMEOUT + 2
    assert slowest < 1.0, f"a health check and a listing took {slowest:.2f} s while the calls waited"
    assert gw.get("/health").json()["x-medkit-operations"]["operation_timeouts"] >= 2


def test_member_qualified_ids_and_ambiguity(gw):
    body = gw.get("/functions/dup/operations").json()
    assert sorted(i["id"] for i in body["items"]) == ["a:reset", "b:reset"]
    r = gw.get("/functions/dup/operations/reset")
    assert r.status_code == 400 and r.json()["error_code"] == "invalid-request"
    assert sorted(r.json()["parameters"]["operation_ids"]) == ["a:reset", "b:reset"]
    r = gw.get("/functions/dup/operations/b:reset")
    assert r.status_code == 200 and r.json()["item"]["x-medkit"]["ros2"]["service"] == "/dup/b_ns/reset"
    r = gw.get("/functions/dup/operations/zz:reset")
    assert r.status_code == 404 and r.json()["error_code"] == "resource-not-found"
    assert post(gw, "/functions/dup/operations/a:reset/executions", {}).json()["parameters"]["success"] is True


def test_one_member_two_paths_are_named_by_path(gw):
    ids = sorted(i["id"] for i in gw.get("/apps/c/operations").json()["items"])
    assert ids == ["twice/reset", "twice/sub/reset"]
    assert gw.get("/apps/c/operations/reset").status_code == 400
    r = post(gw, "/apps/c/operations/twice/sub/reset/executions", {})
    assert r.status_code == 200, r.text
    assert gw.get("/apps/c/operations/twice/sub/reset/executions").json() == {"items": []}


def test_a_server_that_leaves_mid_goal_fails_the_goal(gw, servers):
    node = OpsNode({"node": "brief", "namespace": "/gone", "services": [{"name": "calibrate", "type": TRIGGER}],
                    "actions": [{"name": "fib", "type": FIB, "step": 0.2}]})
    try:
        poll_until(lambda: len(gw.get("/apps/brief/operations").json().get("items", [])) == 2, 20,
                   message="brief's operations")
        assert post(gw, "/apps/brief/operations/calibrate/executions", {}).status_code == 200
        r = post(gw, "/apps/brief/operations/fib/executions", {"parameters": {"order": 500}})
        assert r.status_code == 202
        location = gw.url + r.headers["Location"]
        assert requests.get(location, timeout=10).json()["status"] == "running"
        node.stop()   # SIGTERM: the node is destroyed and leaves the graph at once
        body = poll_until(lambda: (lambda b: b if b["status"] == "failed" else None)(
            requests.get(location, timeout=10).json()), 20, message="goal failed after its server left")
        assert body["x-medkit"]["ros2_status"] == "unknown"
        assert "left" in body["x-medkit"]["message"]
    finally:
        node.stop()


JSON = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=20),
                    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=10), inner,
                                                                                 max_size=4), max_leaves=12)
FIELDS = st.dictionaries(st.sampled_from(["bool_value", "int8_value", "uint64_value", "float32_value",
                                          "string_value", "order", "x", ""]), JSON, max_size=4)


@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
@given(body=st.one_of(JSON, st.fixed_dictionaries({"parameters": FIELDS}),
                      st.fixed_dictionaries({"goal": FIELDS, "type": JSON})))
def test_hostile_bodies_get_json_errors_and_never_kill_the_worker(gw, body):
    for path in ("/apps/c/operations/twice/reset/executions", "/functions/dup/operations/a:reset/executions"):
        r = requests.post(gw.api + path, data=json.dumps(body), timeout=15,
                          headers={**AUTH, "Content-Type": "application/json"})
        assert r.status_code in (200, 400), r.text
        assert r.headers["Content-Type"] == "application/json"
        if r.status_code == 400:
            assert r.json()["error_code"] in ("invalid-request", "invalid-parameter", "vendor-error")
    assert gw.get("/health").json()["x-medkit-subscription-executor"]["worker_alive"]


def test_no_server_of_the_asked_type_is_503_with_retry_after(gw):
    """A type override no server of the path serves: the client never matches, 503 (not a hang)."""
    r = post(gw, "/apps/c/operations/twice/reset/executions", {"parameters": {}, "type": "std_srvs/srv/Empty"})
    assert r.status_code == 503, r.text
    assert r.json()["vendor_code"] == "x-medkit-ros2-service-unavailable" and r.headers["Retry-After"]
    r = post(gw, "/functions/dup/operations/a:reset/executions", {})
    assert r.status_code == 200, r.text   # the path's own type still works
