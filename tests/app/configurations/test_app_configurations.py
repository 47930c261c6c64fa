"""{entity}/configurations on the HTTP side: the write gate, the path and body checks, the error answers.

The ROS worker is the fake one (tests/support/fakeworker.py); the routes with real nodes are
tests/system/configurations/test_configurations.py.
"""

from __future__ import annotations

import pytest

from ipc.errors import IpcError
from tests.support.fakeworker import make_app

URL = "/api/v1/apps/controller/configurations/rate"
TOKEN = "cfg-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}

pytestmark = pytest.mark.fakeworker(allow_configurations=True, api_token=TOKEN)


def param_calls(fw) -> list[str]:
    return [c for c, _, _ in fw.requests if c.startswith("param_")]


def test_writes_are_off_by_default(fw):
    client = make_app(fw).test_client()
    for r in (client.put(URL, json={"data": 1}), client.delete(URL),
              client.delete("/api/v1/apps/controller/configurations")):
        assert r.status_code == 403, r.data
        assert "allow-configurations" in r.get_json()["parameters"]["details"]
    assert param_calls(fw) == []


def test_writes_need_the_token(client, fw):
    r = client.put(URL, json={"data": 1})
    assert r.status_code == 401 and r.headers["WWW-Authenticate"].startswith("Bearer")
    assert client.delete(URL, headers={"Authorization": "Bearer not-the-token-at-all"}).status_code == 401
    assert param_calls(fw) == []


def test_reads_are_open(fw):
    fw.errors["param_get"] = IpcError("no-such-parameter", "Parameter not found: rate", {"name": "rate"})
    r = make_app(fw).test_client().get(URL)
    assert r.status_code == 404
    # medkit's answer when no node has it: no details (config_handlers.cpp, all_not_found)
    assert r.get_json() == {"error_code": "resource-not-found", "message": "Parameter not found",
                            "parameters": {"entity_id": "controller", "id": "rate"}}
    assert fw.calls("param_get") == [{"node": "/body/lights/controller", "name": "rate"}]


def test_parameter_id_too_long(client):
    r = client.get("/api/v1/apps/controller/configurations/" + "a" * 513)
    assert r.status_code == 400 and r.get_json()["error_code"] == "invalid-parameter"
    assert r.get_json()["parameters"] == {"details": "Parameter ID is empty or too long"}


@pytest.mark.parametrize("value", [None, {"a": 1}, [[1]], [1, {"b": 2}]])
def test_values_no_parameter_can_hold_are_400_before_the_ros_worker(client, fw, value):
    r = client.put(URL, json={"data": value}, headers=AUTH)
    assert r.status_code == 400 and r.get_json()["error_code"] == "invalid-parameter", r.data
    assert fw.calls("param_set") == []


def test_legacy_value_field_is_accepted(client, fw):
    fw.errors["param_set"] = IpcError("parameter-read-only", "Trying to set a read-only parameter: rate.")
    r = client.put(URL, json={"value": 3}, headers=AUTH)
    assert fw.calls("param_set") == [{"node": "/body/lights/controller", "name": "rate", "value": 3}]
    assert r.status_code == 403
    assert r.get_json() == {"error_code": "vendor-error", "vendor_code": "x-medkit-ros2-parameter-read-only",
                            "message": "Failed to set parameter",
                            "parameters": {"details": "Trying to set a read-only parameter: rate.",
                                           "entity_id": "controller", "id": "rate"}}


def test_node_unavailable_is_503_with_the_remaining_wait(client, fw):
    fw.errors["param_reset"] = IpcError("node-unavailable", "Parameter service did not respond for node: "
                                        "/body/lights/controller (within 2 s)", {"retry_after_s": 7})
    r = client.delete(URL, headers=AUTH)
    assert r.status_code == 503 and r.headers["Retry-After"] == "7"
    assert r.get_json()["vendor_code"] == "x-medkit-ros2-node-unavailable"
    assert r.get_json()["message"] == "Failed to reset parameter"


def test_areas_have_no_configurations(client):
    assert client.get("/api/v1/areas/x/configurations").status_code == 404
