"""What a trigger may hold, and the store of them all, through the real gateway.

A condition's ``target_value`` has a size limit (a 400 that names it), the records of every
trigger together have a byte cap (``max_trigger_bytes``: the next trigger is refused, nothing held
is touched), and the triggers are rows of the state dir's SQLite store, one written per change.
"""

from __future__ import annotations

import os
import sqlite3

import psutil
import pytest
import requests

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from ipc.errors import IpcError
from tests.support.linepub import LinePublisher

APP = f"trig_store_{os.getpid()}"
TOPIC = "/trig_store/value"
CAP = 64 * 1024


@pytest.fixture(scope="module")
def pub():
    node = LinePublisher(APP, TOPIC, "std_msgs/msg/Float64")
    yield node
    node.stop()


@pytest.fixture(scope="module")
def gw(pub, gateway):
    gw = gateway("--workers", "1", "--log-level", "warning", "--max-trigger-bytes", str(CAP))
    poll_until(lambda: gw.get(f"/apps/{APP}").status_code == 200, 30, message="the app")
    return gw


def post(gw: Gateway, target_value, **fields) -> requests.Response:
    return requests.post(f"{gw.api}/apps/{APP}/triggers", json={
        "resource": f"/api/v1/apps/{APP}/data{TOPIC}", "path": "/data", "multishot": True,
        "trigger_condition": {"condition_type": "OnChangeTo", "target_value": target_value}, **fields}, timeout=30)


def rows(gw: Gateway) -> dict[str, int]:
    """The trigger rows of the store: id -> length of the record."""
    db = sqlite3.connect(f"file:{os.path.join(gw.state_dir, 'faults.db')}?mode=ro", uri=True)
    try:
        return {i: len(doc) for i, doc in db.execute("SELECT id, doc FROM triggers")}
    finally:
        db.close()


def delete_all(gw: Gateway) -> None:
    for item in gw.get(f"/apps/{APP}/triggers").json()["items"]:
        assert requests.delete(f"{gw.api}/apps/{APP}/triggers/{item['id']}", timeout=10).status_code == 204


def test_a_target_value_past_the_limit_is_a_400_that_names_it(gw):
    r = post(gw, "x" * 5000)
    assert r.status_code == 400, r.text
    body = r.json()
    assert body["error_code"] == "invalid-parameter" and "4096" in body["message"]
    assert body["parameters"]["parameter"] == "trigger_condition.target_value"
    assert body["parameters"]["max_bytes"] == 4096 and body["parameters"]["bytes"] == 5002
    nested = post(gw, {"limits": [list(range(400)) for _ in range(3)]})  # any JSON value counts by its text
    assert nested.status_code == 400 and nested.json()["parameters"]["max_bytes"] == 4096
    assert post(gw, 1.0, path="/" + "a" * 1024).json()["message"] == "Path too long (max 1024)"
    # the ROS worker holds to the same limit, whoever asks it
    client = gw.rosworker_client()
    try:
        with pytest.raises(IpcError) as refused:
            client.call("trig_create", {"collection": "apps", "entity_id": APP, "resource": "/r", "source": "data",
                                        "target": TOPIC, "bytes": "array", "path": "",
                                        "condition": {"condition_type": "OnChangeTo", "target_value": "x" * 5000}}, 5)
    finally:
        client.close()
    assert refused.value.code == "bad-request" and refused.value.params["max_bytes"] == 4096
    fits = post(gw, "y" * 4000)
    assert fits.status_code == 201, fits.text
    assert gw.get(f"/apps/{APP}/triggers/{fits.json()['id']}").json()["trigger_condition"]["target_value"] == "y" * 4000
    delete_all(gw)


def test_sixty_conditions_of_almost_a_megabyte_leave_the_ros_worker_as_it_was(gw):
    """The review's attack: 60 triggers whose target_value is just under the body limit took the ROS
    worker from 94 to 245 MB and the store to 57 MB.  Each is refused now, before the ROS worker."""
    worker = psutil.Process(gw.rosworker_pid())
    before = worker.memory_info().rss
    huge = "z" * (900 * 1024)
    for _ in range(60):
        r = post(gw, huge)
        assert r.status_code == 400 and r.json()["parameters"]["parameter"] == "trigger_condition.target_value"
    assert gw.get(f"/apps/{APP}/triggers").json()["items"] == []
    assert rows(gw) == {}
    grown = worker.memory_info().rss - before
    assert grown < 20 * 2**20, f"the ROS worker grew by {grown / 2**20:.1f} MB"  # generous: it is not asked at all


def test_a_store_at_its_cap_refuses_the_next_trigger_and_keeps_every_one_it_holds(gw):
    made = []
    refused = None
    for _ in range(40):  # 64 KiB of records: about 15 of these
        r = post(gw, "v" * 4000, persistent=True)
        if r.status_code != 201:
            refused = r
            break
        made.append(r.json()["id"])
    assert refused is not None, "the cap never answered"
    assert 10 <= len(made) < 20
    assert refused.status_code == 503 and refused.headers["Retry-After"] == "5", refused.text
    body = refused.json()
    assert body["error_code"] == "service-unavailable" and "max_trigger_bytes" in body["message"]
    assert body["parameters"]["max_trigger_bytes"] == CAP
    # nothing held was touched: every trigger is listed, one row each, the ROS worker answers
    listed = [t["id"] for t in gw.get(f"/apps/{APP}/triggers").json()["items"]]
    assert sorted(listed) == sorted(made)
    stored = rows(gw)
    assert sorted(stored) == sorted(made) and sum(stored.values()) <= CAP
    streams = gw.get("/health").json()["x-medkit-streams"]
    assert streams["max_trigger_bytes"] == CAP and sum(stored.values()) <= streams["trigger_bytes"] <= CAP
    # deleting one makes room for another
    assert requests.delete(f"{gw.api}/apps/{APP}/triggers/{made[0]}", timeout=10).status_code == 204
    assert made[0] not in rows(gw)
    again = post(gw, "v" * 4000)
    assert again.status_code == 201, again.text
    delete_all(gw)
    assert rows(gw) == {} and gw.get("/health").json()["x-medkit-streams"]["trigger_bytes"] == 0
