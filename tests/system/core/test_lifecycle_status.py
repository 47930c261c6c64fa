"""``GET /{apps|components}/{id}/status`` through the real gateway, as medkit answers it by default.

Real managed nodes (rclpy ``LifecycleNode``, tests/support/lifecyclenode.py): one left unconfigured,
one active, one whose lifecycle services never answer; and a plain node.  The transitions
(``PUT .../status/{transition}``) stay 501, as medkit's without a lifecycle provider.
"""

from __future__ import annotations

import json
import sys
import time

import pytest
import requests

from common.harness.gateway import Gateway
from common.harness.procs import Proc, poll_until
from tests.support.rospub import RosNode

SPEC = {"namespace": "/lc", "nodes": [{"name": "lc_idle"}, {"name": "lc_running", "activate": True},
                                      {"name": "lc_stuck", "hang": True}]}


class LifecycleNodes(Proc):
    def __init__(self, spec: dict, timeout: float = 20.0):
        super().__init__([sys.executable, "-m", "tests.support.lifecyclenode", json.dumps(spec)],
                         name="lifecycle nodes", stdin=True)
        self.wait_line(lambda line: line == "READY", timeout)

    def transition(self, name: str, transition: str) -> str:
        self.proc.stdin.write(f"{name} {transition}\n")
        self.proc.stdin.flush()
        return self.wait_line(lambda line: line.startswith(f"DONE {name} "), 10).split()[-1]


@pytest.fixture(scope="module")
def robot():
    managed = LifecycleNodes(SPEC)
    plain = RosNode({"node": "lc_plain", "namespace": "/lc", "publish": [
        {"topic": "beat", "type": "std_msgs/msg/Bool", "rate": 1, "value": {"data": True}}]})
    yield managed
    plain.stop()
    managed.stop()


@pytest.fixture(scope="module")
def gw(robot, gateway):
    gw = gateway("--log-level", "warning")
    poll_until(lambda: all(gw.get(f"/apps/{a}").status_code == 200
                           for a in ("lc_idle", "lc_running", "lc_stuck", "lc_plain")), 30, message="the apps")
    return gw


def status(gw: Gateway, path: str) -> str:
    r = gw.get(path + "/status")
    assert r.status_code == 200, r.text
    body = r.json()
    assert set(body) == {"status"}, body  # medkit's default path sends the status only
    return body["status"]


def test_plain_nodes_and_the_host_component_are_ready(gw):
    assert status(gw, "/apps/lc_plain") == "ready"
    assert status(gw, f"/components/{gw.host()}") == "ready"
    detail = gw.get("/apps/lc_plain").json()
    assert detail["status"] == "/api/v1/apps/lc_plain/status"
    assert {"name": "status", "href": "/api/v1/apps/lc_plain/status"} in detail["capabilities"]


def test_a_managed_node_is_ready_only_when_active(gw, robot):
    """In the graph but unconfigured: notReady (read through get_state, not from graph presence)."""
    assert poll_until(lambda: status(gw, "/apps/lc_running") == "ready", 20, message="the active node ready")
    assert status(gw, "/apps/lc_idle") == "notReady"
    assert robot.transition("lc_idle", "configure") == "inactive"
    assert status(gw, "/apps/lc_idle") == "notReady"
    assert robot.transition("lc_idle", "activate") == "active"
    assert status(gw, "/apps/lc_idle") == "ready"
    assert robot.transition("lc_idle", "deactivate") == "inactive"
    assert status(gw, "/apps/lc_idle") == "notReady"


def calls(gw: Gateway) -> int:
    return gw.get("/health").json()["x-medkit-operations"]["operation_calls_total"]


def test_a_node_that_hangs_is_not_ready_within_the_deadline_then_at_once_from_the_negative_cache(gw):
    before = calls(gw)
    started = time.monotonic()
    assert status(gw, "/apps/lc_stuck") == "notReady"
    first = time.monotonic() - started
    assert first < 5  # the ROS worker's deadline (1 s), not the HTTP side's
    assert calls(gw) == before + 1
    for _ in range(3):
        started = time.monotonic()
        assert status(gw, "/apps/lc_stuck") == "notReady"
        assert time.monotonic() - started < 1.0
    assert calls(gw) == before + 1  # asked once: the others were answered from the negative cache
    assert status(gw, "/apps/lc_plain") == "ready"  # nobody else waited behind it


def test_transitions_stay_501_and_unknown_entities_404(gw):
    for transition in ("start", "restart", "force-restart", "shutdown", "force-shutdown"):
        r = requests.put(f"{gw.api}/apps/lc_running/status/{transition}", json={}, timeout=10)
        assert r.status_code == 501 and r.json()["error_code"] == "not-implemented", r.text
    r = gw.get("/apps/nonexistent_app/status")
    assert r.status_code == 404 and r.json()["error_code"] == "entity-not-found"
