"""{entity}/triggers on faults and logs: what the routes send the ROS worker, and what they refuse.

The fake worker stands in for the ROS worker here; the events themselves, from a
real /diagnostics publisher and real logging nodes through a real gateway, are
tests/system/triggers/test_app_trigger_sources.py.
"""

from __future__ import annotations

import json

import pytest

pytestmark = pytest.mark.fakeworker(scope="module")

NODE = "/powertrain/engine/temp_sensor"


def create(client, entity: str, resource: str, condition: dict | None = None, **fields):
    return client.post(f"/api/v1/{entity}/triggers", json={
        "resource": resource, "trigger_condition": condition or {"condition_type": "OnChange"}, **fields})


def test_an_apps_faults_and_one_fault_code_are_scoped_to_its_node(client, fw):
    r = create(client, "apps/temp_sensor", "/api/v1/apps/temp_sensor/faults")
    assert r.status_code == 201, r.data
    sent = fw.calls("trig_create")[-1]
    assert sent["source"] == "faults" and json.loads(sent["target"]) == {"nodes": [NODE], "code": None}
    assert r.get_json()["observed_resource"] == "/api/v1/apps/temp_sensor/faults"
    r = create(client, "apps/temp_sensor", "/api/v1/apps/temp_sensor/faults/ENGINE_OVERHEAT", path="/status")
    assert r.status_code == 201, r.data
    assert json.loads(fw.calls("trig_create")[-1]["target"]) == {"nodes": [NODE], "code": "ENGINE_OVERHEAT"}


def test_a_components_logs_are_those_of_the_apps_it_hosts(client, fw):
    components = client.get("/api/v1/components").get_json()["items"]
    host = next(c["id"] for c in components
                if any(a["id"] == "temp_sensor"
                       for a in client.get(f"/api/v1/components/{c['id']}/hosts").get_json().get("items", [])))
    r = create(client, f"components/{host}", f"/api/v1/components/{host}/logs",
               {"condition_type": "OnChangeTo", "target_value": "error"}, path="/severity")
    assert r.status_code == 201, r.data
    sent = fw.calls("trig_create")[-1]
    assert sent["source"] == "logs" and NODE in json.loads(sent["target"])["nodes"]


@pytest.mark.parametrize("resource, condition, fields, parameter", [
    ("/api/v1/apps/temp_sensor/faults", {"condition_type": "EnterRange", "lower_bound": 0, "upper_bound": 1}, {},
     "path"),
    ("/api/v1/apps/temp_sensor/logs", {"condition_type": "LeaveRange", "lower_bound": 0, "upper_bound": 1}, {},
     "path"),
    ("/api/v1/apps/temp_sensor/logs/configuration", None, {}, "resource"),
    ("/api/v1/apps/temp_sensor/faults/" + "X" * 257, None, {}, "resource"),
    ("/api/v1/apps/temp_sensor/faults/A/B", None, {}, "resource"),
])
def test_what_cannot_apply_is_invalid_parameter_and_nothing_is_made(client, fw, resource, condition, fields,
                                                                    parameter):
    before = len(fw.calls("trig_create"))
    r = create(client, "apps/temp_sensor", resource, condition, **fields)
    assert r.status_code == 400, r.data
    doc = r.get_json()
    assert doc["error_code"] == "invalid-parameter" and doc["parameters"]["parameter"] == parameter, doc
    assert len(fw.calls("trig_create")) == before


def test_another_entitys_faults_or_logs_are_a_mismatch(client, fw):
    for resource in ("/api/v1/apps/controller/faults", "/api/v1/apps/controller/logs"):
        r = create(client, "apps/temp_sensor", resource)
        assert r.status_code == 400 and r.get_json()["vendor_code"] == "x-medkit-entity-mismatch", r.data
