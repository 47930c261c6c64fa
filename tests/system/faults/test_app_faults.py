"""Faults through the real gateway, from real ``/diagnostics`` publishers in other processes.

One gateway for the module (confirm after 3 failing reports, heal after 2 passing ones,
STALE after 4 s, clearing allowed behind a token, one snapshot topic rule); each test uses
status names of its own, so that the faults of one never touch another's.
"""

from __future__ import annotations

import json
import subprocess
import uuid

import pytest
import requests
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from common.harness.gateway import BIN, Gateway
from common.harness.procs import poll_until
from tests.support.rospub import publisher

TOKEN = "fault-clear-token-0123"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture(scope="module")
def gw(gateway):
    return gateway("--fault-confirm-count", "3", "--fault-confirm-s", "60", "--fault-heal-count", "2",
                   "--fault-stale-s", "4", "--allow-fault-clear", "--api-token", TOKEN,
                   "--fault-snapshot-topics", "SNAP_*=/snap_temp", "--max-fault-streams", "2")


def unique(prefix: str) -> tuple[str, str]:
    """A status name of this test and its fault code."""
    tag = uuid.uuid4().hex[:8]
    return f"{prefix}: check {tag}", f"{prefix}_CHECK_{tag}".upper()


def fault(gw: Gateway, code: str, path: str = "/faults?status=all") -> dict | None:
    items = gw.get(path).json()["items"]
    return next((f for f in items if f["fault_code"] == code), None)


def wait_status(gw: Gateway, code: str, status: str, timeout: float = 20.0) -> dict:
    poll_until(lambda: (fault(gw, code) or {}).get("status") == status, timeout,
               message=f"{code} {status}")
    return fault(gw, code)


def known(gw: Gateway, app: str) -> None:
    """Wait until the gateway's graph has the node (under load, discovery may trail a status's first report;
    the fault then names ``/diagnostics`` until a later report names the node)."""
    poll_until(lambda: gw.get(f"/apps/{app}").status_code == 200, 30, message=f"app {app}")


def failing(name: str, level: int = 2, **extra) -> dict:
    return {"name": name, "level": level, "message": "out of range", **extra}


# ---- the lifecycle -------------------------------------------------------------------------------------
def test_a_failing_status_is_prefailed_then_confirmed_after_three_reports_then_healed(gw, diag):
    name, code = unique("lifecycle_driver")
    pub = diag("lifecycle_driver", rate=0.5)  # one report every 2 s: each state can be seen
    known(gw, "lifecycle_driver")  # a driver the graph knows: its first report names it
    pub.set([failing(name, values={"temperature": "97"})])
    first = wait_status(gw, code, "PREFAILED")
    assert first["severity"] == 2 and first["severity_label"] == "ERROR" and first["occurrence_count"] == 1
    assert first["reporting_sources"] == ["/lifecycle_driver"]
    assert fault(gw, code, "/faults?status=pending") is not None
    assert fault(gw, code, "/faults?status=confirmed") is None
    confirmed = wait_status(gw, code, "CONFIRMED")
    assert confirmed["occurrence_count"] == 1 and confirmed["first_occurred"] == first["first_occurred"]
    assert confirmed["last_occurred"] > first["last_occurred"]
    assert fault(gw, code, "/faults") is not None             # the default: the active faults
    assert fault(gw, code, "/faults?status=pending") is None
    # one passing report: PREPASSED (medkit's "healed" filter holds it); the second heals it
    pub.set([{"name": name, "level": 0, "message": "ok"}])
    prepassed = wait_status(gw, code, "PREPASSED")
    assert "last_passed" in prepassed
    wait_status(gw, code, "HEALED")
    assert fault(gw, code, "/faults") is None
    assert fault(gw, code, "/faults?status=healed") is not None
    assert fault(gw, code, "/faults?status=cleared") is not None  # SOVD's cleared holds HEALED too
    # failing again after it healed: the same occurrence (medkit counts a new one only after a clear)
    pub.set([failing(name, level=1)], rate=10)
    again = wait_status(gw, code, "CONFIRMED")
    assert again["occurrence_count"] == 1 and again["severity_label"] == "WARN"


def test_a_stale_level_is_critical_and_confirmed_at_once(gw, diag):
    name, code = unique("stale_level")
    pub = diag("stale_level_driver", rate=0.2)
    pub.set([failing(name, level=3)])
    got = wait_status(gw, code, "CONFIRMED")
    assert got["severity"] == 3 and got["severity_label"] == "CRITICAL"


def test_a_status_that_stops_arriving_turns_stale(gw, diag):
    name, code = unique("silent_driver")
    pub = diag("silent_driver", rate=10)
    known(gw, "silent_driver")
    pub.set([{"name": name, "level": 0, "message": "ok"}])
    pub.set([{"name": name, "level": 0, "message": "ok"}], publish=False)  # the driver hangs
    got = wait_status(gw, code, "CONFIRMED", timeout=30)
    assert got["severity_label"] == "CRITICAL" and got["description"].startswith("stale")
    assert got["reporting_sources"] == ["/silent_driver"]
    # it comes back: its OK reports heal the fault
    pub.set([{"name": name, "level": 0, "message": "ok"}])
    wait_status(gw, code, "HEALED")


# ---- one fault, its detail and snapshots -----------------------------------------------------------------
def test_the_detail_has_medkit_s_shape_and_the_freeze_frame(gw, diag):
    name, code = unique("detail_driver")
    pub = diag("detail_driver")
    pub.set([failing(name, hardware_id="", values={"voltage": "10.5", "cells": "4"})])
    wait_status(gw, code, "CONFIRMED")
    body = gw.get(f"/apps/detail_driver/faults/{code}").json()
    assert body["item"] == {"code": code, "fault_name": "out of range", "severity": 2,
                            "status": {"aggregatedStatus": "active", "testFailed": "1", "confirmedDTC": "1",
                                       "pendingDTC": "0"}}
    records = body["environment_data"]["extended_data_records"]
    assert records["first_occurrence"].endswith("Z") and records["last_occurrence"] >= records["first_occurrence"]
    assert body["x-medkit"]["occurrence_count"] == 1 and body["x-medkit"]["severity_label"] == "ERROR"
    assert body["x-medkit"]["reporting_sources"] == ["/detail_driver"] and body["x-medkit"]["status_raw"] == "CONFIRMED"
    frame = body["environment_data"]["snapshots"][0]
    assert frame["type"] == "freeze_frame" and frame["name"] == name
    assert frame["data"]["values"] == {"voltage": "10.5", "cells": "4"}
    assert frame["x-medkit"]["topic"] == "/diagnostics"
    assert frame["x-medkit"]["message_type"] == "diagnostic_msgs/msg/DiagnosticStatus"


def test_the_snapshot_topics_of_a_code_are_captured_at_confirmation(gw, diag, nodes):
    nodes.append(publisher("snap_sensor", "/snap_temp", "std_msgs/msg/Float64", {"data": 42.5}, rate=10))
    tag = uuid.uuid4().hex[:6]
    name, code = f"snap temp {tag}", f"SNAP_TEMP_{tag.upper()}"
    pub = diag("snap_driver", rate=1)
    pub.set([failing(name)])
    wait_status(gw, code, "CONFIRMED")
    # The app's scope holds the fault once the graph knows the node (discovery may trail its first report).
    detail = poll_until(lambda: (r := gw.get(f"/apps/snap_driver/faults/{code}")).status_code == 200 and r, 20,
                        message="the fault in its app's scope")
    snapshots = detail.json()["environment_data"]["snapshots"]
    topic = next(s for s in snapshots if s["x-medkit"]["topic"] == "/snap_temp")
    assert topic["data"] == 42.5                          # medkit's primary value of a Float64
    assert topic["x-medkit"]["full_data"] == {"data": 42.5}
    assert topic["x-medkit"]["message_type"] == "std_msgs/msg/Float64"


# ---- entity scope ------------------------------------------------------------------------------------------
def test_faults_are_scoped_to_the_app_component_and_function_of_their_source(gw, diag):
    name_a, code_a = unique("scope_a")
    name_b, code_b = unique("scope_b")
    diag("scope_a", "/fleet_a").set([failing(name_a)])
    diag("scope_b", "/fleet_b").set([failing(name_b)])
    wait_status(gw, code_a, "CONFIRMED")
    wait_status(gw, code_b, "CONFIRMED")

    def codes(path: str) -> set[str]:
        return {f["fault_code"] for f in gw.get(path).json()["items"]}

    # A status that came before the graph knew its node is the topic's until the next report names it.
    poll_until(lambda: code_a in codes("/apps/scope_a/faults") and code_b in codes("/apps/scope_b/faults"), 20,
               message="each fault in its app's scope")
    assert fault(gw, code_a)["reporting_sources"] == ["/fleet_a/scope_a"]

    assert code_a in codes("/apps/scope_a/faults") and code_b not in codes("/apps/scope_a/faults")
    assert code_b in codes("/apps/scope_b/faults") and code_a not in codes("/apps/scope_b/faults")
    assert {code_a, code_b} <= codes(f"/components/{gw.host()}/faults")
    assert code_a in codes("/functions/fleet_a/faults") and code_b not in codes("/functions/fleet_a/faults")
    app = gw.get("/apps/scope_a/faults").json()["x-medkit"]
    assert app["entity_id"] == "scope_a" and app["source_id"] == "/fleet_a/scope_a" and app["count"] >= 1
    func = gw.get("/functions/fleet_a/faults").json()["x-medkit"]
    assert func["aggregation_level"] == "function" and func["aggregated"] is True
    assert func["aggregation_sources"] == ["/fleet_a/scope_a"] and func["host_count"] == 1
    comp = gw.get(f"/components/{gw.host()}/faults").json()["x-medkit"]
    assert comp["aggregation_level"] == "component" and comp["app_count"] >= 2
    # out of scope: not found there, found where it belongs
    r = gw.get(f"/apps/scope_b/faults/{code_a}")
    assert r.status_code == 404 and r.json()["error_code"] == "resource-not-found"
    assert "not in scope" in r.json()["parameters"]["details"]
    assert gw.get(f"/functions/fleet_a/faults/{code_a}").status_code == 200
    assert gw.get(f"/components/{gw.host()}/faults/{code_a}").status_code == 200
    # a clear through another app is refused the same way, and clears nothing
    r = requests.delete(f"{gw.api}/apps/scope_b/faults/{code_a}", headers=AUTH, timeout=10)
    assert r.status_code == 404
    assert fault(gw, code_a)["status"] == "CONFIRMED"


# ---- errors -------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("path", ["/faults", "/apps/{app}/faults", "/components/{host}/faults"])
def test_an_unknown_status_filter_is_400_invalid_parameter(gw, diag, path):
    diag("filter_driver").set([])
    poll_until(lambda: gw.get("/apps/filter_driver").status_code == 200, 20, message="app listed")
    url = path.format(app="filter_driver", host=gw.host())
    for bad in ("active", "", "ALL", "pending,confirmed"):
        r = gw.get(url, params={"status": bad})
        assert r.status_code == 400, (url, bad)
        body = r.json()
        assert body["error_code"] == "invalid-parameter" and body["message"] == "Invalid status parameter value"
        assert body["parameters"]["parameter"] == "status" and body["parameters"]["value"] == bad
        assert body["parameters"]["allowed_values"] == "pending, confirmed, cleared, healed, all"
    for good in ("pending", "confirmed", "cleared", "healed", "all"):
        assert gw.get(url, params={"status": good}).status_code == 200


def test_unknown_faults_entities_and_codes(gw, diag):
    diag("codes_driver").set([])
    poll_until(lambda: gw.get("/apps/codes_driver").status_code == 200, 20, message="app listed")
    r = gw.get("/apps/codes_driver/faults/NO_SUCH_FAULT")
    assert r.status_code == 404 and r.json()["message"] == "Fault not found"
    assert r.json()["parameters"]["fault_code"] == "NO_SUCH_FAULT"
    r = gw.get("/apps/codes_driver/faults/" + "X" * 257)
    assert r.status_code == 400 and r.json()["message"] == "Invalid fault code"
    assert gw.get("/apps/no_such_app/faults").json()["error_code"] == "entity-not-found"
    assert gw.get("/apps/no_such_app/faults/X").status_code == 404
    r = requests.delete(f"{gw.api}/apps/codes_driver/faults/NO_SUCH_FAULT", headers=AUTH, timeout=10)
    assert r.status_code == 404


# ---- clearing ---------------------------------------------------------------------------------------------
def test_clearing_needs_the_token_and_makes_the_fault_cleared(gw, diag):
    name, code = unique("clear_driver")
    pub = diag("clear_driver", rate=1)
    pub.set([failing(name)])
    wait_status(gw, code, "CONFIRMED")
    url = f"{gw.api}/apps/clear_driver/faults/{code}"
    assert requests.delete(url, timeout=10).status_code == 401
    assert requests.delete(url, headers={"Authorization": "Bearer wrong"}, timeout=10).status_code == 401
    assert fault(gw, code)["status"] == "CONFIRMED"
    r = requests.delete(url, headers=AUTH, timeout=10)
    assert r.status_code == 204 and r.content == b""
    assert fault(gw, code)["status"] == "CLEARED"
    assert fault(gw, code, "/faults") is None and fault(gw, code, "/faults?status=cleared") is not None
    # still failing: a failing report after a clear is a new occurrence
    again = wait_status(gw, code, "CONFIRMED")
    assert again["occurrence_count"] == 2


def test_clear_all_of_an_entity_clears_only_its_faults(gw, diag):
    name_a, code_a = unique("clear_all_a")
    name_b, code_b = unique("clear_all_b")
    pub_a = diag("clear_all_a", rate=1)
    pub_b = diag("clear_all_b", rate=1)
    pub_a.set([failing(name_a)])
    pub_b.set([failing(name_b)])
    wait_status(gw, code_a, "CONFIRMED")
    wait_status(gw, code_b, "CONFIRMED")
    pub_a.set([], publish=False)  # no new occurrence after the clear
    assert requests.delete(f"{gw.api}/apps/clear_all_a/faults?status=bogus", headers=AUTH,
                           timeout=10).status_code == 400
    r = requests.delete(f"{gw.api}/apps/clear_all_a/faults", headers=AUTH, timeout=10)
    assert r.status_code == 204
    assert fault(gw, code_a)["status"] == "CLEARED" and fault(gw, code_b)["status"] == "CONFIRMED"


# ---- the stream ---------------------------------------------------------------------------------------------
def read_events(lines, count: int) -> list[dict]:
    """``count`` events (id, event, data) from an SSE response's ``iter_lines()``."""
    out, current = [], {}
    for raw in lines:
        line = raw.decode()
        if not line:
            if "data" in current:
                out.append(current)
                if len(out) == count:
                    return out
            current = {}
        elif not line.startswith(":"):
            key, _, value = line.partition(": ")
            current[key] = json.loads(value) if key == "data" else value
    return out


def test_the_stream_sends_confirmations_and_clears_and_replays_after_last_event_id(gw, diag):
    name, code = unique("stream_driver")
    with requests.get(f"{gw.api}/faults/stream", stream=True, timeout=30) as stream:
        assert stream.status_code == 200 and stream.headers["Content-Type"].startswith("text/event-stream")
        pub = diag("stream_driver", rate=2)
        pub.set([failing(name)])
        wait_status(gw, code, "CONFIRMED")
        pub.set([], publish=False)
        assert requests.delete(f"{gw.api}/apps/stream_driver/faults/{code}", headers=AUTH, timeout=10).status_code == 204
        mine = []
        lines = stream.iter_lines()
        while len(mine) < 2:
            event = read_events(lines, 1)[0]
            if event["data"]["fault"]["fault_code"] == code:
                mine.append(event)
    confirmed, cleared = mine
    assert confirmed["event"] == "fault_confirmed" and confirmed["data"]["event_type"] == "fault_confirmed"
    assert confirmed["data"]["fault"]["status"] == "CONFIRMED" and isinstance(confirmed["data"]["timestamp"], float)
    assert cleared["event"] == "fault_cleared" and cleared["data"]["fault"]["status"] == "CLEARED"
    assert int(cleared["id"]) > int(confirmed["id"])
    # reconnecting after the confirmation: the clear is replayed from the store
    with requests.get(f"{gw.api}/faults/stream", stream=True, timeout=30,
                      headers={"Last-Event-ID": confirmed["id"]}) as again:
        replayed = read_events(again.iter_lines(), 1)[0]
    assert replayed["id"] == str(int(confirmed["id"]) + 1)
    assert int(replayed["id"]) <= int(cleared["id"])


def test_fault_streams_are_counted_with_every_other_stream(gw, diag):
    """/health's x-medkit-streams (and /metrics) cover fault streams too (issue 30: one hub base)."""
    def streams() -> dict:
        return gw.get("/health").json()["x-medkit-streams"]

    # no stream is left open by this module's other tests once their clients' leaving is noticed
    poll_until(lambda: streams()["open_streams"] == 0, 10, message="no stream open")
    before = streams()
    name, code = unique("counted_driver")
    with requests.get(f"{gw.api}/faults/stream", stream=True, timeout=30) as stream:
        assert stream.status_code == 200
        poll_until(lambda: streams()["open_streams"] == 1, 10,
                   message="the fault stream counted in open_streams")
        diag("counted_driver", rate=2).set([failing(name)])
        lines = stream.iter_lines()
        while read_events(lines, 1)[0]["data"]["fault"]["fault_code"] != code:
            pass
        poll_until(lambda: streams()["frames_sent"] > before["frames_sent"], 10,
                   message="the fault stream's events counted in frames_sent")
    poll_until(lambda: streams()["open_streams"] == 0, 10,
               message="the closed fault stream no longer counted")


def test_fault_streams_are_bounded_per_http_worker(gw):
    # every HTTP worker holds at most 2 (max_fault_streams); 2 workers: the fifth is refused
    opened = []
    try:
        for _ in range(5):
            r = requests.get(f"{gw.api}/faults/stream", stream=True, timeout=30)
            opened.append(r)
            if r.status_code == 503:
                break
        assert opened[-1].status_code == 503
        body = opened[-1].json()
        assert body["error_code"] == "service-unavailable" and "Maximum number of SSE clients" in body["message"]
    finally:
        for r in opened:
            r.close()

    # a client that leaves frees its slot within a second or so (not at the next keep-alive, 15 s on)
    def opens() -> bool:
        with requests.get(f"{gw.api}/faults/stream", stream=True, timeout=30) as r:
            return r.status_code == 200

    poll_until(opens, 10, interval=0.5, message="a stream slot freed")


# ---- health, metrics, capabilities ---------------------------------------------------------------------
def test_health_metrics_and_capabilities_show_the_faults(gw, diag):
    name, code = unique("health_driver")
    diag("health_driver", rate=5).set([failing(name)])
    wait_status(gw, code, "CONFIRMED")
    section = gw.get("/health").json()["x-medkit-faults"]
    assert section["active"] >= 1 and section["confirmed"] >= 1 and section["store_size"] >= 1
    assert section["last_write_error"] == "" and section["store_enabled"] is True
    metrics = requests.get(gw.url + "/metrics", timeout=10).text
    line = next(x for x in metrics.splitlines() if x.startswith('sovd_faults_active{severity="ERROR"}'))
    assert float(line.split()[-1]) >= 1
    assert gw.get("/").json()["capabilities"]["faults"] is True
    # sovd-probe faults: the same, from a shell on the robot
    probe = subprocess.run([str(BIN / "sovd-probe"), "--runtime-dir", gw.runtime_dir, "faults"],
                           capture_output=True, text=True, timeout=30)
    assert probe.returncode == 0, probe.stderr
    line = next(x for x in probe.stdout.splitlines() if x.startswith(code))
    assert "CONFIRMED" in line and "ERROR" in line and "/health_driver" in line
    probe = subprocess.run([str(BIN / "sovd-probe"), "--runtime-dir", gw.runtime_dir, "--json", "faults", "--all"],
                           capture_output=True, text=True, timeout=30)
    assert code in {f["fault_code"] for f in json.loads(probe.stdout)["result"]["items"]}


# ---- hostile queries -------------------------------------------------------------------------------------
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(status=st.text(max_size=40), code=st.text(min_size=1, max_size=300))
def test_hostile_queries_get_json_answers(gw, status, code):
    assume(code.strip(".") != "")  # "." and ".." are path segments, not codes
    r = gw.get("/faults", params={"status": status})
    assert r.status_code == (200 if status in ("pending", "confirmed", "cleared", "healed", "all") else 400)
    r = gw.get(f"/components/{gw.host()}/faults/" + requests.utils.quote(code, safe=""))
    assert r.status_code in (400, 404) and r.headers["Content-Type"].startswith("application/json"), r.text
    r = requests.delete(f"{gw.api}/faults", params={"status": status}, timeout=10)
    assert r.status_code == 401  # nothing is cleared without the token, whatever the query
