"""``{entity}/logs`` and ``logs/configuration`` through a real gateway, fed by real nodes logging to /rosout.

The nodes are rclpy processes of their own (``common/harness/roslogger.py``); the
gateway is the operator's ``sovd-gateway`` with two HTTP workers.  Covered: the
answer's shape (medkit's), the severity and context filters, the aggregation
over a component and a function, every error, the configuration shared by
both HTTP workers, the bearer token on PUT, and hostile queries (hypothesis).
The storm and the caps are in ``tests/system/logs/test_app_logs_storm.py``.
"""

from __future__ import annotations

import re
import uuid

import pytest
import requests
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from common.harness.roslogger import LoggerNode

TOKEN = "logs-secret-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
STAMP = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{9}Z$")


@pytest.fixture(scope="module")
def env():
    """A gateway (two HTTP workers, an API token) and two logging nodes in namespaces of their own."""
    tag = uuid.uuid4().hex[:6]
    gw = Gateway("--workers", "2", "--api-token", TOKEN, "--debug-commands", "--log-level", "warning")
    started = []
    try:
        first = LoggerNode(f"logger_a_{tag}", f"/ns_a_{tag}")
        started.append(first)
        second = LoggerNode(f"logger_b_{tag}", f"/ns_b_{tag}")
        started.append(second)
        for app in (f"logger_a_{tag}", f"logger_b_{tag}"):
            poll_until(lambda app=app: gw.get(f"/apps/{app}").status_code == 200, 20, message=f"app {app}")
        first.log(("debug", "a debug line"), ("info", "a info line"), ("warning", "a warning line"),
                  ("error", "a error line"), ("fatal", "a fatal line"))
        second.log(("info", "b info line"), ("error", "b error line"))
        yield {"gw": gw, "a": f"logger_a_{tag}", "b": f"logger_b_{tag}", "ns_a": f"ns_a_{tag}",
               "ns_b": f"ns_b_{tag}", "nodes": (first, second)}
    finally:
        for node in reversed(started):
            node.stop()
        gw.stop()


def _items(gw: Gateway, path: str, count: int) -> list[dict]:
    """The items at ``path`` once there are at least ``count`` of them."""
    return poll_until(lambda: (lambda items: items if len(items) >= count else None)(gw.get(path).json()["items"]),
                      15, message=f"{count} log lines at {path}")


def test_an_apps_logs_are_its_nodes_lines_in_medkits_shape_oldest_first(env):
    gw = env["gw"]
    items = _items(gw, f"/apps/{env['a']}/logs", 5)
    assert [i["message"] for i in items] == ["a debug line", "a info line", "a warning line", "a error line",
                                             "a fatal line"]
    assert [i["severity"] for i in items] == ["debug", "info", "warning", "error", "fatal"]
    numbers = [int(i["id"].removeprefix("log_")) for i in items]
    assert numbers == sorted(numbers) and all(i["id"].startswith("log_") for i in items)
    for i in items:
        assert set(i) == {"id", "timestamp", "severity", "message", "context"}
        assert STAMP.match(i["timestamp"]), i["timestamp"]
        assert i["context"]["node"] == f"{env['ns_a']}.{env['a']}"
        assert i["context"]["file"].endswith("roslogger.py") and i["context"]["line"] > 0
        assert i["context"]["function"]
    assert "x-medkit" not in gw.get(f"/apps/{env['a']}/logs").json()  # an app: not aggregated (medkit)


def test_severity_is_a_minimum_and_context_a_substring_of_the_logger_name(env):
    gw = env["gw"]
    _items(gw, f"/apps/{env['a']}/logs", 5)
    got = gw.get(f"/apps/{env['a']}/logs", params={"severity": "warning"}).json()["items"]
    assert [i["severity"] for i in got] == ["warning", "error", "fatal"]
    assert gw.get(f"/apps/{env['a']}/logs", params={"severity": ""}).json()["items"][0]["severity"] == "debug"
    assert len(gw.get(f"/apps/{env['a']}/logs", params={"context": env["ns_a"]}).json()["items"]) == 5
    assert gw.get(f"/apps/{env['a']}/logs", params={"context": "not-in-any-name"}).json()["items"] == []
    assert len(gw.get(f"/apps/{env['a']}/logs", params={"context": "x" * 256}).json()["items"]) == 0


def test_a_component_and_a_function_aggregate_their_apps(env):
    gw = env["gw"]
    host = gw.host()
    _items(gw, f"/apps/{env['b']}/logs", 2)
    # each HTTP worker learns the component's apps from its own graph snapshot: wait for this one's
    body = poll_until(lambda: (lambda b: b if "b error line" in [i["message"] for i in b["items"]] else None)(
        gw.get(f"/components/{host}/logs", params={"severity": "error"}).json()), 15, message="b's line aggregated")
    messages = [i["message"] for i in body["items"]]
    assert "a error line" in messages and "b error line" in messages and "a fatal line" in messages
    assert all(i["severity"] in ("error", "fatal") for i in body["items"])
    ext = body["x-medkit"]
    assert ext["aggregation_level"] == "component" and ext["aggregated"] is True and ext["entity_id"] == host
    assert f"/{env['ns_a']}/{env['a']}" in ext["aggregation_sources"] and ext["app_count"] == len(
        ext["aggregation_sources"])
    func = gw.get(f"/functions/{env['ns_b']}/logs").json()
    assert [i["message"] for i in func["items"]] == ["b info line", "b error line"]
    assert func["x-medkit"] == {"entity_id": env["ns_b"], "aggregation_level": "function", "aggregated": True,
                                "host_count": 1, "aggregation_sources": [f"/{env['ns_b']}/{env['b']}"]}


@pytest.mark.parametrize(("path", "params", "status", "code"), [
    ("/apps/{a}/logs", {"severity": "warn"}, 400, "invalid-parameter"),
    ("/apps/{a}/logs", {"severity": "WARNING"}, 400, "invalid-parameter"),
    ("/apps/{a}/logs", {"context": "x" * 257}, 400, "invalid-parameter"),
    ("/apps/no_such_app/logs", {}, 404, "entity-not-found"),
    ("/apps/bad.id/logs", {}, 400, "invalid-parameter"),
    ("/components/{a}/logs", {}, 400, "invalid-parameter"),   # an app's id under components
    ("/apps/no_such_app/logs/configuration", {}, 404, "entity-not-found"),
    ("/areas/anything/logs", {}, 404, "entity-not-found"),
])
def test_errors(env, path, params, status, code):
    r = env["gw"].get(path.format(a=env["a"]), params=params)
    assert r.status_code == status, r.text
    assert r.json()["error_code"] == code and r.json()["message"]


def test_an_unknown_entity_is_named_before_a_bad_query(env):
    r = env["gw"].get("/apps/no_such_app/logs", params={"severity": "loud"})
    assert r.status_code == 404 and r.json()["error_code"] == "entity-not-found"


def test_the_configuration_is_shared_by_both_http_workers_and_applies_to_queries(env):
    gw = env["gw"]
    _items(gw, f"/apps/{env['a']}/logs", 5)
    path = f"{gw.api}/apps/{env['a']}/logs"
    sessions = gw.worker_sessions()
    one, other = sessions.values()
    try:
        assert one.get(path + "/configuration", timeout=15).json() == {"severity_filter": "debug",
                                                                       "max_entries": 100}
        r = one.put(path + "/configuration", json={"severity_filter": "warning"}, headers=AUTH, timeout=15)
        assert r.status_code == 204 and r.content == b""
        assert other.get(path + "/configuration", timeout=15).json() == {"severity_filter": "warning",
                                                                         "max_entries": 100}
        assert [i["severity"] for i in other.get(path, timeout=15).json()["items"]] == ["warning", "error", "fatal"]
        # The stricter of the query's and the configuration's severity.
        assert [i["severity"] for i in other.get(path, params={"severity": "info"}, timeout=15).json()["items"]] \
            == ["warning", "error", "fatal"]
        assert [i["severity"] for i in other.get(path, params={"severity": "fatal"}, timeout=15).json()["items"]] \
            == ["fatal"]
        r = other.put(path + "/configuration", json={"max_entries": 2}, headers=AUTH, timeout=15)
        assert r.status_code == 204
        assert one.get(path + "/configuration", timeout=15).json() == {"severity_filter": "warning",
                                                                       "max_entries": 2}
        assert [i["message"] for i in one.get(path, timeout=15).json()["items"]] == ["a error line", "a fatal line"]
        # Another entity keeps the defaults.
        assert one.get(f"{gw.api}/apps/{env['b']}/logs/configuration", timeout=15).json()["max_entries"] == 100
    finally:
        one.put(path + "/configuration", json={"severity_filter": "debug", "max_entries": 100}, headers=AUTH,
                timeout=15)
        for s in sessions.values():
            s.close()


@pytest.mark.parametrize(("body", "status", "code"), [
    ({"severity_filter": "loud"}, 400, "invalid-parameter"),
    ({"severity_filter": 3}, 400, "invalid-parameter"),
    ({"max_entries": 0}, 400, "invalid-parameter"),
    ({"max_entries": -5}, 400, "invalid-parameter"),
    ({"max_entries": 10001}, 400, "invalid-parameter"),
    ({"max_entries": "50"}, 400, "invalid-parameter"),
    ({"max_entries": True}, 400, "invalid-parameter"),
    ({"max_entries": 2.5}, 400, "invalid-parameter"),
    ([1, 2], 400, "invalid-request"),
])
def test_put_configuration_refuses_bad_values_and_changes_nothing(env, body, status, code):
    gw = env["gw"]
    path = f"/apps/{env['b']}/logs/configuration"
    r = gw.put(path, json=body, headers=AUTH)
    assert r.status_code == status, r.text
    assert r.json()["error_code"] == code
    assert gw.get(path).json() == {"severity_filter": "debug", "max_entries": 100}


def test_put_configuration_asks_the_token_and_json(env):
    gw = env["gw"]
    path = f"/apps/{env['b']}/logs/configuration"
    r = gw.put(path, json={"max_entries": 5})
    assert r.status_code == 401 and r.json()["error_code"] == "unauthorized"
    r = gw.put(path, json={"max_entries": 5}, headers={"Authorization": "Bearer wrong"})
    assert r.status_code == 401 and r.json()["error"] == "invalid_token"   # medkit's answer to a bad token
    r = gw.put(path, data="max_entries=5", headers={**AUTH, "Content-Type": "text/plain"})
    assert r.status_code == 415
    assert gw.get(path).json()["max_entries"] == 100
    assert gw.put(path, json={}, headers=AUTH).status_code == 204  # both fields optional
    assert gw.put(path, json={"max_entries": 10000}, headers=AUTH).status_code == 204
    assert gw.get(path).json() == {"severity_filter": "debug", "max_entries": 10000}
    assert gw.put(path, json={"max_entries": 100}, headers=AUTH).status_code == 204


def test_health_and_metrics_show_the_buffers(env):
    gw = env["gw"]
    _items(gw, f"/apps/{env['a']}/logs", 5)
    logs = gw.get("/health").json()["x-medkit-logs"]
    assert logs["logs_buffered"] >= 7 and logs["logs_received"] >= 7 and logs["logs_nodes"] >= 2
    assert logs["logs_buffer_size"] == 200 and logs["logs_dropped"] == 0
    text = requests.get(gw.url + "/metrics", timeout=15).text
    assert re.search(r"^sovd_ros_logs_buffered \d", text, re.M) and "sovd_ros_logs_received_total" in text


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(severity=st.text(max_size=40), context=st.text(max_size=300))
def test_hostile_queries_get_an_answer_or_a_contract_error(env, severity, context):
    gw = env["gw"]
    r = gw.get(f"/apps/{env['a']}/logs", params={"severity": severity, "context": context})
    if r.status_code == 200:
        body = r.json()
        assert severity in ("", "debug", "info", "warning", "error", "fatal") and len(context.encode()) <= 256
        assert all(context in i["context"]["node"] for i in body["items"])
    else:
        assert r.status_code == 400, r.text
        assert r.json()["error_code"] == "invalid-parameter"
