"""Triggers on faults and logs through a real gateway: a real /diagnostics publisher, real logging nodes.

One gateway for the module (faults confirmed after 3 failing reports); each
test uses nodes and status names of its own.  What is checked: a trigger on an
app's faults fires when a fault of that app is confirmed, with medkit's payload
(the fault as listed, plus ``event_type``); ``…/faults/{code}`` sees that code
only; a trigger on an app's logs fires on a matching line of that app's node
and not on another node's; the entity checks and the conditions that cannot
apply to these collections are refused before anything is made.
"""

from __future__ import annotations

import os
import shutil
import signal
import tempfile
import uuid

import pytest
import requests

from common.harness.diagpub import DiagPub
from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from common.harness.roslogger import LoggerNode
from tests.support.sse import EventStream

TOKEN = "trigger-sources-secret"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture(scope="module")
def gw(gateway):
    return gateway("--workers", "2", "--log-level", "warning", "--api-token", TOKEN,
                   "--fault-confirm-count", "3", "--fault-confirm-s", "60", "--fault-heal-count", "2")


def tag() -> str:
    return uuid.uuid4().hex[:8]


def app_shows(gw: Gateway, app: str) -> None:
    poll_until(lambda: gw.get(f"/apps/{app}").status_code == 200, 30, message=f"app {app}")


def create(gw: Gateway, app: str, resource: str, condition: dict, **fields) -> requests.Response:
    return requests.post(f"{gw.api}/apps/{app}/triggers", json={"resource": resource, "trigger_condition": condition,
                                                                "protocol": "sse", **fields},
                         headers=AUTH, timeout=10)


def stream(gw: Gateway, trigger: dict) -> EventStream:
    opened = EventStream(gw.port, trigger["event_source"])
    assert opened.status == 200, opened.body
    assert opened.headers["content-type"].startswith("text/event-stream")
    return opened


def failing(name: str, level: int = 2) -> dict:
    return {"name": name, "level": level, "message": "out of range", "values": {"temperature": "97"}}


# ---- faults ---------------------------------------------------------------------------------------
def test_a_trigger_on_an_apps_faults_fires_when_a_fault_is_confirmed_with_medkits_payload(gw):
    node = f"trgf_{tag()}"
    pub = DiagPub(node, rate=10)
    try:
        app_shows(gw, node)
        r = create(gw, node, f"/api/v1/apps/{node}/faults", {"condition_type": "OnChangeTo",
                                                             "target_value": "CONFIRMED"}, path="/status")
        assert r.status_code == 201, r.text
        trigger = r.json()
        assert trigger["observed_resource"] == f"/api/v1/apps/{node}/faults" and trigger["status"] == "active"
        assert trigger["path"] == "/status" and trigger["multishot"] is False
        name, code = f"{node}: motor {tag()}", None
        with stream(gw, trigger) as events:
            pub.set([failing(name)])
            event = events.next(timeout=15)
            assert event is not None, "no event when the fault was confirmed"
            payload = event["payload"]
            code = payload["fault_code"]
            assert code == name.upper().replace(": ", "_").replace(" ", "_")
            assert payload["event_type"] == "fault_confirmed" and payload["status"] == "CONFIRMED"
            assert payload["severity"] == 2 and payload["severity_label"] == "ERROR"
            assert payload["reporting_sources"] == [f"/{node}"] and payload["occurrence_count"] == 1
            assert {"description", "first_occurred", "last_occurred"} <= payload.keys()
            assert event["timestamp"].endswith("Z") and "error" not in event
            assert events.ended(10), "a one-shot trigger's stream ends after its event"
        # the payload is the fault as the faults route lists it, plus event_type
        listed = next(f for f in gw.get(f"/apps/{node}/faults").json()["items"] if f["fault_code"] == code)
        assert listed["status"] == "CONFIRMED" and listed["reporting_sources"] == payload["reporting_sources"]
        poll_until(lambda: gw.get(f"/apps/{node}/triggers/{trigger['id']}").json().get("status") == "terminated",
                   10, message="the one-shot trigger terminated")
    finally:
        pub.stop()


def test_a_trigger_on_one_fault_code_sees_that_code_only_and_another_apps_faults_are_out_of_scope(gw):
    node, other = f"trgc_{tag()}", f"trgo_{tag()}"
    pub, other_pub = DiagPub(node, rate=10), DiagPub(other, rate=10)
    try:
        app_shows(gw, node)
        watched, unwatched = f"{node}: watched {tag()}", f"{node}: unwatched {tag()}"
        code = watched.upper().replace(": ", "_").replace(" ", "_")
        by_code = create(gw, node, f"/api/v1/apps/{node}/faults/{code}", {"condition_type": "OnChange"},
                         path="/status", multishot=True)
        whole = create(gw, node, f"/api/v1/apps/{node}/faults", {"condition_type": "OnChange"},
                       path="/fault_code", multishot=True, lifetime=120)
        assert by_code.status_code == 201 and whole.status_code == 201, (by_code.text, whole.text)
        with stream(gw, by_code.json()) as one, stream(gw, whole.json()) as every:
            other_pub.set([failing(f"{other}: elsewhere {tag()}")])   # another app's fault: out of scope
            pub.set([failing(watched), failing(unwatched, level=1)])
            confirmed = one.next(timeout=15)
            assert confirmed["payload"]["status"] == "CONFIRMED", confirmed
            assert confirmed["payload"]["event_type"] == "fault_confirmed"
            pub.set([{"name": watched, "level": 0, "message": "ok"}, failing(unwatched, level=1)])  # it heals
            got = [one.next(timeout=15) for _ in range(2)]
            assert [e["payload"]["status"] for e in got] == ["PREPASSED", "HEALED"]
            assert [e["payload"]["event_type"] for e in got] == ["fault_updated", "fault_updated"]
            assert {e["payload"]["fault_code"] for e in [confirmed, *got]} == {code}
            # OnChange on /fault_code: each event whose code differs from the previous one's, this app's only
            seen = [e["payload"] for e in every.collect(2.0)]
            assert seen and all(p["reporting_sources"] == [f"/{node}"] for p in seen)
            assert {p["fault_code"] for p in seen} == {code, unwatched.upper().replace(": ", "_").replace(" ", "_")}
            assert one.collect(0.5) == []   # the unwatched code's events did not reach the code's trigger
    finally:
        pub.stop()
        other_pub.stop()


# ---- logs -------------------------------------------------------------------------------------------
def test_a_trigger_on_an_apps_logs_fires_on_a_matching_line_of_its_node_only(gw):
    node, other = f"trgl_{tag()}", f"trgn_{tag()}"
    logger, other_logger = LoggerNode(node), LoggerNode(other)
    try:
        app_shows(gw, node)
        r = create(gw, node, f"/api/v1/apps/{node}/logs", {"condition_type": "OnChangeTo", "target_value": "error"},
                   path="/severity", multishot=True)
        assert r.status_code == 201, r.text
        with stream(gw, r.json()) as events:
            other_logger.log(("info", "elsewhere calm"), ("error", "elsewhere broken"))
            logger.log(("info", "all good"), ("error", "overheat"), ("error", "still hot"), ("info", "cooled"),
                       ("fatal", "gone"), ("error", "back again"))
            got = [events.next(timeout=15) for _ in range(2)]
            assert [e["payload"]["message"] for e in got] == ["overheat", "back again"]
            first = got[0]["payload"]
            assert first["severity"] == "error" and first["id"].startswith("log_")
            assert first["context"]["node"].endswith(node) and first["timestamp"].endswith("Z")
            assert events.collect(0.5) == []   # the other node's error line and the repeats did not fire
        # the payload is the line as the logs route lists it
        listed = [i for i in gw.get(f"/apps/{node}/logs").json()["items"] if i["message"] == "overheat"]
        assert listed == [first]
    finally:
        logger.stop()
        other_logger.stop()


# ---- what is refused ------------------------------------------------------------------------------------
def test_refusals_entity_mismatch_and_conditions_that_cannot_apply(gw):
    node = f"trgr_{tag()}"
    logger = LoggerNode(node)
    try:
        app_shows(gw, node)
        before = gw.get(f"/apps/{node}/triggers").json()["items"]
        cases = [
            ("/api/v1/apps/somebody_else/faults", {"condition_type": "OnChange"}, {}, "vendor-error",
             "x-medkit-entity-mismatch"),
            (f"/api/v1/components/{node}/logs", {"condition_type": "OnChange"}, {}, "vendor-error",
             "x-medkit-entity-mismatch"),
            (f"/api/v1/apps/{node}/faults", {"condition_type": "EnterRange", "lower_bound": 1, "upper_bound": 3},
             {}, "invalid-parameter", None),
            (f"/api/v1/apps/{node}/logs", {"condition_type": "LeaveRange", "lower_bound": 0, "upper_bound": 9},
             {}, "invalid-parameter", None),
            (f"/api/v1/apps/{node}/logs/configuration", {"condition_type": "OnChange"}, {}, "invalid-parameter",
             None),
            (f"/api/v1/apps/{node}/faults/{'X' * 300}", {"condition_type": "OnChange"}, {}, "invalid-parameter",
             None),
            (f"/api/v1/apps/{node}/operations", {"condition_type": "OnChange"}, {}, "invalid-parameter", None),
        ]
        for resource, condition, fields, error_code, vendor_code in cases:
            r = create(gw, node, resource, condition, **fields)
            assert r.status_code == 400, (resource, r.text)
            doc = r.json()
            assert doc["error_code"] == error_code and doc.get("vendor_code") == vendor_code, (resource, doc)
            assert doc["message"] and doc["parameters"]["parameter"] in ("resource", "path"), doc
        ranged = create(gw, node, f"/api/v1/apps/{node}/faults", {"condition_type": "EnterRange", "lower_bound": 1,
                                                                  "upper_bound": 3})
        assert ranged.json()["parameters"]["parameter"] == "path"
        assert "needs a 'path'" in ranged.json()["message"]
        assert gw.get(f"/apps/{node}/triggers").json()["items"] == before   # nothing was made
        # with a path to a number the same range condition is accepted
        ok = create(gw, node, f"/api/v1/apps/{node}/logs", {"condition_type": "EnterRange", "lower_bound": 1,
                                                            "upper_bound": 10 ** 6}, path="/context/line")
        assert ok.status_code == 201, ok.text
        assert requests.delete(f"{gw.api}/apps/{node}/triggers/{ok.json()['id']}", headers=AUTH,
                               timeout=10).status_code == 204
    finally:
        logger.stop()


# ---- restarts -----------------------------------------------------------------------------------------
def test_faults_and_logs_triggers_survive_a_ros_worker_sigkill_and_fire_after_it():
    runtime_dir = tempfile.mkdtemp(prefix="sovd-trigsrc-")
    os.chmod(runtime_dir, 0o700)
    gateway = Gateway("--workers", "1", "--log-level", "warning", "--fault-confirm-count", "2",
                      runtime_dir=runtime_dir)
    node = f"trgk_{tag()}"
    logger = pub = None
    try:
        logger, pub = LoggerNode(node), DiagPub(node, rate=10)
        app_shows(gateway, node)
        logs = create(gateway, node, f"/api/v1/apps/{node}/logs",
                      {"condition_type": "OnChangeTo", "target_value": "after restart"}, path="/message",
                      multishot=True, persistent=True)
        faults = create(gateway, node, f"/api/v1/apps/{node}/faults",
                        {"condition_type": "OnChangeTo", "target_value": "CONFIRMED"}, path="/status",
                        persistent=True)
        assert logs.status_code == 201 and faults.status_code == 201, (logs.text, faults.text)
        logger.log(("info", "before the restart"))
        old = gateway.rosworker_pid()
        os.kill(old, signal.SIGKILL)
        poll_until(lambda: gateway.rosworker_pid() != old and gateway.get("/health").json()[
            "x-medkit-subscription-executor"]["worker_alive"], 30, message="the ROS worker restarted")
        # The new ROS worker lists the app once its first graph poll has found the node again.
        listing = poll_until(lambda: (r := gateway.get(f"/apps/{node}/triggers")).status_code == 200 and r, 30,
                             message="the app's triggers listed by the restarted ROS worker")
        listed = {t["id"]: t for t in listing.json()["items"]}
        assert set(listed) == {logs.json()["id"], faults.json()["id"]}
        assert all(t["status"] == "active" for t in listed.values())
        with stream(gateway, logs.json()) as lines, stream(gateway, faults.json()) as confirmed:
            poll_until(lambda: (logger.log(("info", "after restart")) or True) and lines.collect(0.3), 20,
                       message="a line after the restart fired the restored logs trigger")
            pub.set([failing(f"{node}: after {tag()}")])
            event = confirmed.next(timeout=15)
            assert event["payload"]["status"] == "CONFIRMED" and event["payload"]["event_type"] == "fault_confirmed"
    finally:
        for proc in (logger, pub):
            if proc is not None:
                proc.stop()
        gateway.stop()
        shutil.rmtree(runtime_dir, ignore_errors=True)
