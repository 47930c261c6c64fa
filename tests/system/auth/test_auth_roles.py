"""Roles through the real gateway: each of medkit's four roles against each write family, allowed and
refused as ``app/auth/roles.py``'s table says, with real nodes behind the allowed ones.

The gateway runs with ``auth_enabled`` (clients of every role, tests/support/auth.py), every
``allow_*`` switch on and ``require_auth_for=write``: a write without a token is 401, a role the table
refuses 403 (``insufficient_scope``, before anything reaches the robot), a role it allows gets the
family's own answer (a service really called, a parameter really set, a message really heard).  A
second gateway, ``require_auth_for=all``, checks reads the same way (``/health`` included, as medkit's
code; the dashboard's files stay open).
"""

from __future__ import annotations

import json
import sys
import time

import pytest
import requests

from app.auth import roles
from common.harness.gateway import Gateway
from common.harness.procs import Proc, poll_until
from tests.support.auth import ENV, ROLES, bearer, grant
from tests.support.rospub import RosNode

LISTENER = "auth_listener"
CMD = "/auth_test/cmd"


def ros_process(module: str, spec: dict) -> Proc:
    proc = Proc([sys.executable, "-m", module, json.dumps(spec)], name=f"{module} {spec['node']}")
    proc.wait_line(lambda line: line == "READY", 20)
    return proc


@pytest.fixture(scope="module")
def robot():
    nodes = [RosNode({"node": LISTENER, "subscribe": [{"topic": CMD, "type": "std_msgs/msg/String", "echo": True}]}),
             ros_process("tests.support.rosops", {"node": "auth_arm", "services": [
                 {"name": "calibrate", "type": "std_srvs/srv/Trigger"}]}),
             ros_process("tests.support.paramnode", {"node": "auth_tuner", "params": [
                 {"name": "rate", "value": 10.0}]})]
    yield nodes
    for node in nodes:
        node.stop()


@pytest.fixture(scope="module")
def gw(robot, gateway):
    gw = gateway("--auth-enabled", "--allow-publish", "--allow-operations", "--allow-configurations",
                 "--allow-fault-clear", "--allow-bulk-data", "--bulk-data-categories", "logs", "--workers", "2",
                 env=ENV)
    poll_until(lambda: {LISTENER, "auth_arm", "auth_tuner"} <= {a["id"] for a in gw.get("/apps").json()["items"]},
               30, message="the test nodes listed")
    poll_until(lambda: gw.get("/apps/auth_arm/operations").json()["items"], 20, message="the service")
    return gw


@pytest.fixture(scope="module")
def tokens(gw):
    return {role: grant(gw, role) for role in ROLES}


# family -> (method, path, body, what an allowed request answers)
WRITES = {
    "publish": ("PUT", f"/apps/{LISTENER}/data{CMD}", {"type": "std_msgs/msg/String", "data": {"data": "hi"}}, 200),
    "operations": ("POST", "/apps/auth_arm/operations/calibrate/executions", {"parameters": {}}, 200),
    "configurations": ("PUT", "/apps/auth_tuner/configurations/rate", {"data": 12.5}, 200),
    "fault_clear": ("DELETE", "/faults", None, 204),
    "log_configuration": ("PUT", "/apps/auth_tuner/logs/configuration", {"severity_filter": "info"}, 204),
    "cyclic_subscriptions": ("POST", f"/apps/{LISTENER}/cyclic-subscriptions",
                             {"resource": f"/api/v1/apps/{LISTENER}/data{CMD}", "interval": "slow", "duration": 5}, 201),
    "triggers": ("POST", f"/apps/{LISTENER}/triggers",
                 {"resource": f"/api/v1/apps/{LISTENER}/data{CMD}", "trigger_condition": {"condition_type": "OnChange"},
                  "lifetime": 5}, 201),
    "locks": ("POST", "/apps/auth_arm/locks", {"lock_expiration": 30, "scopes": ["modes"]}, 201),
    "bulk_data": ("POST", f"/apps/{LISTENER}/bulk-data/logs", None, 201),  # an upload (multipart: _write)
}


def _write(gw, family: str, method: str, path: str, body, headers: dict) -> requests.Response:
    if family == "bulk_data":
        return gw.request(method, path, files={"file": ("role.log", b"written by a role")}, headers=headers)
    return gw.request(method, path, json=body, headers=headers)


def undo(gw, family: str, answer: requests.Response, headers: dict) -> None:
    """Remove what an allowed write made, so that the next role starts from the same robot."""
    body = answer.json() if answer.content else {}
    if family == "cyclic_subscriptions":
        assert gw.request("DELETE", f"/apps/{LISTENER}/cyclic-subscriptions/{body['id']}", headers=headers).status_code == 204
    elif family == "triggers":
        assert gw.request("DELETE", f"/apps/{LISTENER}/triggers/{body['id']}", headers=headers).status_code == 204
    elif family == "locks":
        assert gw.request("DELETE", f"/apps/auth_arm/locks/{body['id']}", headers=headers).status_code == 204
    elif family == "bulk_data":
        gone = gw.request("DELETE", f"/apps/{LISTENER}/bulk-data/logs/{body['id']}", headers=headers)
        assert gone.status_code == 204, gone.text


@pytest.mark.parametrize("role", ROLES)
def test_each_role_may_do_what_the_table_says_and_nothing_else(gw, tokens, role):
    may = roles.summary(role)
    for family, (method, path, body, success) in WRITES.items():
        headers = bearer(tokens[role])
        r = _write(gw, family, method, path, body, headers)
        if may[family]:
            assert r.status_code == success, (role, family, r.status_code, r.text[:300])
            undo(gw, family, r, headers)
        else:
            assert r.status_code == 403, (role, family, r.status_code, r.text[:300])
            assert r.json()["error"] == "insufficient_scope" and r.json()["error_code"] == "forbidden"


def test_the_roles_differ_where_medkits_table_differs():
    """The table is not all-or-nothing: operators publish but do not configure, only admin triggers."""
    table = {role: roles.summary(role) for role in ROLES}
    assert [table[r]["publish"] for r in ROLES] == [False, True, True, True]
    assert [table[r]["configurations"] for r in ROLES] == [False, False, True, True]
    assert [table[r]["fault_clear"] for r in ROLES] == [False, True, True, True]   # medkit's code, not its docs
    assert [table[r]["triggers"] for r in ROLES] == [False, False, False, True]
    assert [table[r]["audit"] for r in ROLES] == [False, False, False, True]


def test_allowed_writes_reach_the_robot(gw, tokens, robot):
    """An operator's publish is heard by the real subscriber; a configurator's set is read back."""
    r = gw.put(f"/apps/{LISTENER}/data{CMD}", json={"type": "std_msgs/msg/String", "data": {"data": "from-operator"}},
               headers=bearer(tokens["operator"]))
    assert r.status_code == 200
    poll_until(lambda: any(m.get("data", {}).get("data") == "from-operator" for m in robot[0].echoed()), 10,
               message="the operator's message heard")
    assert gw.put("/apps/auth_tuner/configurations/rate", json={"data": 33.0},
                  headers=bearer(tokens["configurator"])).status_code == 200
    assert gw.get("/apps/auth_tuner/configurations/rate").json()["data"] == 33.0


def test_refused_writes_change_nothing(gw, tokens, robot):
    heard = len(robot[0].echoed())
    for headers in ({}, bearer(tokens["viewer"]), {"Authorization": "Bearer not-a-token"}):
        r = gw.put(f"/apps/{LISTENER}/data{CMD}", json={"type": "std_msgs/msg/String", "data": {"data": "no"}},
                   headers=headers)
        assert r.status_code in (401, 403), r.text
        if r.status_code == 401:
            assert r.headers["WWW-Authenticate"].startswith("Bearer")
            assert r.json()["error"] == "invalid_token"
    time.sleep(1.0)  # a refused message would have been heard by now (the allowed one took milliseconds)
    assert len(robot[0].echoed()) == heard


def test_writes_need_a_token_and_reads_do_not(gw):
    r = gw.request("POST", "/apps/auth_arm/operations/calibrate/executions", json={"parameters": {}})
    assert r.status_code == 401 and r.json()["error_description"] == "Missing Authorization header"
    # medkit: the check runs before routing, so a write to a route that does not exist is 401 too
    assert gw.request("POST", "/components/nope/operations/nope").status_code == 401
    assert gw.get(f"/apps/{LISTENER}/data{CMD}").status_code == 200
    assert gw.get("/health").status_code == 200


def test_the_overview_says_how_authentication_works(gw):
    body = gw.get("/").json()
    assert body["capabilities"]["authentication"] is True and body["capabilities"]["locking"] is True
    assert body["auth"] == {"enabled": True, "algorithm": "HS256", "require_auth_for": "write"}


# ---- require_auth_for=all: reads too --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def closed(robot):
    gateway = Gateway("--auth-enabled", "--require-auth-for", "all", "--workers", "1",
                      env={**ENV, "SOVD_API_TOKEN": "legacy-admin-token-0123456789"})
    yield gateway
    gateway.stop()


def test_under_all_every_read_needs_a_token_and_the_role_table_applies(closed):
    viewer = bearer(grant(closed, "viewer"))
    poll_until(lambda: LISTENER in {a["id"] for a in closed.get("/apps", headers=viewer).json()["items"]}, 30,
               message="the listener listed")
    for path in ("/health", "/", "/apps", f"/apps/{LISTENER}/data", "/faults", "/docs"):
        r = closed.get(path)
        assert r.status_code == 401, (path, r.status_code)
        assert closed.get(path, headers=viewer).status_code == 200, path
    assert requests.get(closed.url + "/metrics", timeout=10).status_code == 401
    assert requests.get(closed.url + "/metrics", headers=viewer, timeout=10).status_code == 200
    # medkit's table lists no trigger route for a viewer: under "all" a viewer cannot even read them
    r = closed.get(f"/apps/{LISTENER}/triggers", headers=viewer)
    assert r.status_code == 403 and r.json()["error"] == "insufficient_scope"
    assert closed.get(f"/apps/{LISTENER}/triggers", headers=bearer(grant(closed, "admin"))).status_code == 200
    # the sign-in stays reachable, and so does the dashboard that shows it
    assert requests.get(closed.url + "/ui/", timeout=10).status_code == 200
    assert grant(closed, "operator")["scope"] == "operator"
