"""Request ids: kept when valid, made when not, on every answer, and sent across the IPC.

That the ROS worker's log lines of a command carry the id, and that one grep
finds both sides of a slow request, is checked through a real gateway in
``tests/system/fleet/test_fleet_e2e.py``; the worker's refusal of a malformed id in
``tests/rosworker/core/test_rosworker_executor.py`` (hostile IPC frames).
"""

from __future__ import annotations

import pytest

from ipc.protocol import valid_request_id
from tests.support.fakeworker import data_sample, make_app

TOPIC = "/powertrain/engine/temperature"
pytestmark = pytest.mark.fakeworker(scope="module", client_scope="module", samples={
    TOPIC: data_sample(TOPIC, "sensor_msgs/msg/Temperature", {"temperature": 1.0})})


@pytest.mark.parametrize("incoming", ["abc-123", "0f8fad5b-d9cb-469f-a165-70867728950e", "x" * 128,
                                      "trace.v1_A"])
def test_a_valid_incoming_id_is_kept(client, incoming):
    r = client.get("/api/v1/version-info", headers={"X-Request-Id": incoming})
    assert r.headers["X-Request-Id"] == incoming


@pytest.mark.parametrize("incoming", ["", "x" * 129, "has space", "semi;colon", "new\\nline", "ünï"])
def test_anything_else_is_replaced_by_a_fresh_id(client, incoming):
    r = client.get("/api/v1/version-info", headers={"X-Request-Id": incoming})
    assert r.headers["X-Request-Id"] != incoming
    assert valid_request_id(r.headers["X-Request-Id"])


def test_every_answer_carries_an_id_errors_and_refusals_included(fw, client):
    ids = set()
    for path in ("/api/v1/version-info", "/api/v1/apps/nope", "/no/such/route", "/metrics", "/api/v1/health"):
        r = client.get(path)
        assert valid_request_id(r.headers.get("X-Request-Id")), path
        ids.add(r.headers["X-Request-Id"])
    assert len(ids) == 5  # a new one each time
    limited = make_app(fw, rate_limit="0.01/1").test_client()
    limited.get("/api/v1/apps")
    refused = limited.get("/api/v1/apps")  # burst 1: the rate limiter's 429
    assert refused.status_code == 429
    assert valid_request_id(refused.headers.get("X-Request-Id"))


def test_the_id_crosses_the_ipc_in_the_request_envelope(fw, client):
    r = client.get(f"/api/v1/apps/temp_sensor/data{TOPIC}", headers={"X-Request-Id": "rid-sample-1"})
    assert r.status_code == 200
    sent = [e for e in fw.envelopes if e.get("cmd") == "sample" and e.get("request_id") == "rid-sample-1"]
    assert len(sent) == 1
    # Calls outside any request (the stream hub's reports, the supervisor's pings) carry none.
    from ipc.client import RosWorkerClient

    other = RosWorkerClient.for_runtime_dir(fw.runtime_dir)
    try:
        other.call("graph", timeout=2)
    finally:
        other.close()
    assert "request_id" not in [e for e in fw.envelopes if e.get("cmd") == "graph"][-1]
