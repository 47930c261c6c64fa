"""SOVD locks through the real gateway: two clients, scopes, expiry, breaking, a component's lock over
its apps and functions, a token's client id as the owner, and a lock that outlives a SIGKILLed ROS
worker.  The checked writes are real: a publish a real subscriber would hear, a log configuration.
"""

from __future__ import annotations

import os
import signal

import pytest
import requests

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from tests.support.auth import ENV, bearer, grant
from tests.support.rospub import RosNode

APP = "lock_listener"
CMD = "/lock_test/cmd"
PUBLISH = ("PUT", f"/apps/{APP}/data{CMD}", {"type": "std_msgs/msg/String", "data": {"data": "x"}})
LOGS = ("PUT", f"/apps/{APP}/logs/configuration", {"severity_filter": "info"})


@pytest.fixture(scope="module")
def listener():
    node = RosNode({"node": APP, "namespace": "/locktest",
                    "subscribe": [{"topic": CMD, "type": "std_msgs/msg/String"}]})
    yield node
    node.stop()


@pytest.fixture(scope="module")
def gw(listener, gateway):
    gw = gateway("--allow-publish", "--allow-bulk-data", "--bulk-data-categories", "logs", "--workers", "2",
                 "--locking-cleanup-interval", "1")
    poll_until(lambda: APP in {a["id"] for a in gw.get("/apps").json()["items"]}, 30, message="listener listed")
    return gw


def as_client(gw, who: str | None, write: tuple, **headers) -> requests.Response:
    method, path, body = write
    if who is not None:
        headers["X-Client-Id"] = who
    return gw.request(method, path, json=body, headers=headers)


def acquire(gw, who: str, path: str = f"/apps/{APP}/locks", **body) -> requests.Response:
    return gw.request("POST", path, json={"lock_expiration": 60, **body}, headers={"X-Client-Id": who})


def release_all(gw) -> None:
    for path in (f"/apps/{APP}/locks", f"/components/{gw.host()}/locks"):
        for lock in gw.get(path).json()["items"]:
            owner = "alice" if gw.get(f"{path}/{lock['id']}", headers={"X-Client-Id": "alice"}).json()["owned"] else "bob"
            assert gw.request("DELETE", f"{path}/{lock['id']}", headers={"X-Client-Id": owner}).status_code == 204


@pytest.fixture
def clean(gw):
    yield gw
    release_all(gw)


def test_a_lock_keeps_other_clients_out_of_its_scopes_only(clean):
    gw = clean
    r = acquire(gw, "alice", scopes=["data"])
    assert r.status_code == 201, r.text
    lock = r.json()
    assert lock["owned"] is True and lock["scopes"] == ["data"] and lock["id"].startswith("lock_")
    assert r.headers["Location"].endswith(f"/apps/{APP}/locks/{lock['id']}")
    for who in ("bob", None):  # another client, and a client that says nothing
        r = as_client(gw, who, PUBLISH)
        assert r.status_code == 409, r.text
        assert r.json() == {"error_code": "lock-broken", "message": f"Entity '{APP}' is locked by another client",
                            "parameters": {"entity_id": APP, "collection": "data", "lock_id": lock["id"]}}
        assert as_client(gw, who, LOGS).status_code == 204  # logs: not in the lock's scopes
    assert as_client(gw, "alice", PUBLISH).status_code == 200
    # the others see it, not as theirs; they may neither take it nor touch it
    assert gw.get(f"/apps/{APP}/locks", headers={"X-Client-Id": "bob"}).json()["items"][0]["owned"] is False
    r = acquire(gw, "bob")
    assert r.status_code == 409 and r.json()["error_code"] == "invalid-request"
    assert r.json()["parameters"] == {"existing_lock_id": lock["id"]}
    for method, body in (("PUT", {"lock_expiration": 30}), ("DELETE", None)):
        r = gw.request(method, f"/apps/{APP}/locks/{lock['id']}", json=body, headers={"X-Client-Id": "bob"})
        assert r.status_code == 403 and r.json()["error_code"] == "forbidden", r.text
    assert gw.request("PUT", f"/apps/{APP}/locks/{lock['id']}", json={"lock_expiration": 30},
                      headers={"X-Client-Id": "alice"}).status_code == 204
    assert gw.request("DELETE", f"/apps/{APP}/locks/{lock['id']}", headers={"X-Client-Id": "alice"}).status_code == 204
    assert as_client(gw, "bob", PUBLISH).status_code == 200  # released: everyone writes again


def test_a_lock_without_scopes_covers_every_collection_and_a_component_lock_covers_its_apps(clean):
    gw = clean
    host = gw.host()
    r = acquire(gw, "alice", f"/components/{host}/locks")
    assert r.status_code == 201 and "scopes" not in r.json()
    function = next(f["id"] for f in gw.get("/functions").json()["items"] if APP in gw.get(
        f"/functions/{f['id']}").json()["x-medkit"].get("hosts", []))
    for write in (PUBLISH, LOGS, ("PUT", f"/functions/{function}/data{CMD}", PUBLISH[2]),
                  ("PUT", f"/components/{host}/data{CMD}", PUBLISH[2])):
        r = as_client(gw, "bob", write)
        assert r.status_code == 409, (write, r.text)
        assert r.json()["parameters"]["entity_id"] == host
        assert as_client(gw, "alice", write).status_code in (200, 204), write
    # an app's own lock does not stop a write addressed to its component (medkit's parent walk goes up only)
    assert gw.request("DELETE", f"/components/{host}/locks/{r.json()['parameters']['lock_id']}",
                      headers={"X-Client-Id": "alice"}).status_code == 204
    assert acquire(gw, "alice").status_code == 201
    assert as_client(gw, "bob", PUBLISH).status_code == 409
    assert as_client(gw, "bob", ("PUT", f"/components/{host}/data{CMD}", PUBLISH[2])).status_code == 200


def test_a_lock_expires_and_can_be_broken(clean):
    gw = clean
    before = gw.get("/health").json()["x-medkit-locks"]
    short = acquire(gw, "alice", lock_expiration=1).json()
    assert as_client(gw, "bob", PUBLISH).status_code == 409
    poll_until(lambda: as_client(gw, "bob", PUBLISH).status_code == 200, 10, message="the lock expired")
    poll_until(lambda: gw.get("/health").json()["x-medkit-locks"]["locks_expired"] > before["locks_expired"], 10,
               message="the sweep counted it")
    assert gw.get(f"/apps/{APP}/locks/{short['id']}").status_code == 404
    held = acquire(gw, "alice").json()
    r = acquire(gw, "bob", break_lock=True)
    assert r.status_code == 201 and r.json()["id"] != held["id"]
    assert as_client(gw, "alice", PUBLISH).status_code == 409 and as_client(gw, "bob", PUBLISH).status_code == 200
    after = gw.get("/health").json()["x-medkit-locks"]
    assert after["locks_broken"] == before["locks_broken"] + 1 and after["locks_held"] == 1
    assert after["locks_acquired"] == before["locks_acquired"] + 3
    assert after["lock_refusals"] >= before["lock_refusals"] + 3
    metrics = requests.get(gw.url + "/metrics", timeout=10).text
    assert "sovd_ros_locks_broken_total" in metrics and "sovd_http_lock_refusals_total" in metrics


def test_locks_are_answered_as_medkit_answers_them(clean):
    gw = clean
    cases = [
        (gw.request("POST", f"/apps/{APP}/locks", json={"lock_expiration": 60}), 400, "Missing required X-Client-Id header"),
        (acquire(gw, "alice", lock_expiration=0), 400, "Invalid lock_expiration"),
        (acquire(gw, "alice", lock_expiration=3601), 400, "Expiration exceeds maximum allowed (3600s)"),
        (acquire(gw, "alice", scopes=["secrets"]), 400, "Unknown lock scope: secrets"),
        (acquire(gw, "alice", "/apps/nope/locks"), 404, "Entity not found"),
        (gw.get(f"/apps/{APP}/locks/lock_99999"), 404, "Lock not found"),
        (gw.request("POST", f"/apps/{APP}/locks", json={"lock_expiration": 5}, headers={"X-Client-Id": "a\tb"}), 400,
         "X-Client-Id contains invalid characters"),
    ]
    for r, status, message in cases:
        assert (r.status_code, r.json()["message"]) == (status, message), r.text


def test_a_lock_survives_a_sigkilled_ros_worker(clean):
    gw = clean
    lock = acquire(gw, "alice", scopes=["data"], lock_expiration=600).json()
    pid = gw.rosworker_pid()
    os.kill(pid, signal.SIGKILL)
    poll_until(lambda: gw.rosworker_pid() != pid and gw.get("/health").json()["x-medkit-subscription-executor"]
               ["worker_alive"], 60, message="a new ROS worker answering")
    listed = gw.get(f"/apps/{APP}/locks", headers={"X-Client-Id": "alice"}).json()["items"]
    assert [(item["id"], item["owned"], item["scopes"]) for item in listed] == [(lock["id"], True, ["data"])]
    assert listed[0]["lock_expiration"] == lock["lock_expiration"]  # the same deadline (monotonic, kept)
    poll_until(lambda: gw.get(f"/apps/{APP}/data{CMD}").status_code == 200, 30, message="the graph back")
    assert as_client(gw, "bob", PUBLISH).status_code == 409
    assert as_client(gw, "alice", PUBLISH).status_code == 200
    assert acquire(gw, "bob").status_code == 409


def test_with_auth_on_the_owner_is_the_tokens_client_and_a_header_never_overrides_it(listener):
    gateway = Gateway("--auth-enabled", "--allow-publish", env=ENV)
    try:
        poll_until(lambda: APP in {a["id"] for a in gateway.get("/apps").json()["items"]}, 30, message="listed")
        operator, configurator = bearer(grant(gateway, "operator")), bearer(grant(gateway, "configurator"))
        r = gateway.request("POST", f"/apps/{APP}/locks", json={"lock_expiration": 60},
                            headers={**operator, "X-Client-Id": "configurator"})
        assert r.status_code == 201  # no X-Client-Id needed with a token; the one given changes nothing
        lock = r.json()["id"]
        mine = gateway.get(f"/apps/{APP}/locks/{lock}", headers={**configurator, "X-Client-Id": "operator"}).json()
        assert mine["owned"] is False
        write = {"type": "std_msgs/msg/String", "data": {"data": "x"}}
        r = gateway.put(f"/apps/{APP}/data{CMD}", json=write, headers={**configurator, "X-Client-Id": "operator"})
        assert r.status_code == 409
        assert gateway.put(f"/apps/{APP}/data{CMD}", json=write, headers=operator).status_code == 200
        assert gateway.request("DELETE", f"/apps/{APP}/locks/{lock}", headers=configurator).status_code == 403
        assert gateway.request("DELETE", f"/apps/{APP}/locks/{lock}", headers=operator).status_code == 204
    finally:
        gateway.stop()


def test_locking_off_answers_501_and_checks_nothing(listener):
    gateway = Gateway("--allow-publish", "--no-locking-enabled")
    try:
        r = gateway.request("POST", f"/apps/{APP}/locks", json={"lock_expiration": 60}, headers={"X-Client-Id": "a"})
        assert r.status_code == 501 and r.json()["message"] == "Locking is not enabled on this gateway"
        assert gateway.get("/").json()["capabilities"]["locking"] is False
    finally:
        gateway.stop()


def test_a_bulk_data_lock_keeps_other_clients_uploads_and_deletes_out(clean):
    """bulk-data (issue 32) is one of the lock's scopes like every write family: upload and delete."""
    gw = clean
    base = f"/apps/{APP}/bulk-data/logs"

    def upload(who: str) -> requests.Response:
        return gw.request("POST", base, files={"file": ("l.log", b"a log")}, headers={"X-Client-Id": who})

    mine = upload("bob")
    assert mine.status_code == 201, mine.text
    lock = acquire(gw, "alice", scopes=["bulk-data"]).json()
    r = upload("bob")
    assert r.status_code == 409 and r.json()["parameters"] == {"entity_id": APP, "collection": "bulk-data",
                                                               "lock_id": lock["id"]}, r.text
    r = gw.request("DELETE", f"{base}/{mine.json()['id']}", headers={"X-Client-Id": "bob"})
    assert r.status_code == 409, r.text
    assert [f["id"] for f in gw.get(base).json()["items"]] == [mine.json()["id"]]  # nothing lost, nothing added
    assert as_client(gw, "bob", PUBLISH).status_code == 200  # data: not in the lock's scopes
    ours = upload("alice")
    assert ours.status_code == 201, ours.text
    for item in (ours, mine):
        assert gw.request("DELETE", f"{base}/{item.json()['id']}", headers={"X-Client-Id": "alice"}).status_code == 204
