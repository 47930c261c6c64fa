"""{entity}/triggers: what a client sends is checked with medkit's rules and texts.

The registry behind these routes is the ROS worker's (the fake worker stands
in here); conditions, events, lifetimes and persistence through a real
gateway with real publishers are in tests/system/triggers/test_app_trigger_streams.py.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ipc.errors import IpcError
from tests.support.fakeworker import error_of

BASE = "/api/v1/apps/temp_sensor/triggers"
RESOURCE = "/api/v1/apps/temp_sensor/data/powertrain/engine/temperature"

pytestmark = pytest.mark.fakeworker(scope="module")


def body(**changes):
    out = {"resource": RESOURCE, "trigger_condition": {"condition_type": "OnChange"}}
    out.update(changes)
    return {k: v for k, v in out.items() if v is not ...}


def test_create_answers_201_with_medkits_fields(client, fw):
    r = client.post(BASE, json=body(multishot=True, lifetime=120, path="/temperature"))
    assert r.status_code == 201, r.data
    doc = r.get_json()
    assert doc["id"].startswith("trig_") and doc["status"] == "active"
    assert doc["observed_resource"] == RESOURCE and doc["protocol"] == "sse"
    assert doc["event_source"] == f"{BASE}/{doc['id']}/events"
    assert doc["trigger_condition"] == {"condition_type": "OnChange"}
    assert doc["multishot"] is True and doc["persistent"] is False and doc["lifetime"] == 120
    assert doc["path"] == "/temperature"
    assert r.headers["Location"] == f"{BASE}/{doc['id']}"
    sent = fw.calls("trig_create")[-1]
    assert sent["target"] == "/powertrain/engine/temperature" and sent["bytes"] == "array"
    assert sent["source"] == "data" and sent["path"] == "/temperature"


def test_defaults_one_shot_not_persistent_no_lifetime(client):
    doc = client.post(BASE, json=body()).get_json()
    assert doc["multishot"] is False and doc["persistent"] is False and "lifetime" not in doc and "path" not in doc


def test_each_condition_keeps_its_own_fields_only(client, fw):
    for condition, kept in [
        ({"condition_type": "OnChangeTo", "target_value": {"a": [1, None]}, "junk": 1},
         {"condition_type": "OnChangeTo", "target_value": {"a": [1, None]}}),
        ({"condition_type": "OnChangeTo", "target_value": None}, {"condition_type": "OnChangeTo", "target_value": None}),
        ({"condition_type": "EnterRange", "lower_bound": -1, "upper_bound": 2.5},
         {"condition_type": "EnterRange", "lower_bound": -1, "upper_bound": 2.5}),
        ({"condition_type": "LeaveRange", "lower_bound": 3, "upper_bound": 3},
         {"condition_type": "LeaveRange", "lower_bound": 3, "upper_bound": 3}),
    ]:
        r = client.post(BASE, json=body(trigger_condition=condition))
        assert r.status_code == 201, r.data
        assert r.get_json()["trigger_condition"] == kept
        assert fw.calls("trig_create")[-1]["condition"] == kept


@pytest.mark.parametrize("changes, message", [
    ({"trigger_condition": ...}, "Missing or invalid 'trigger_condition'"),
    ({"trigger_condition": "OnChange"}, "Missing or invalid 'trigger_condition'"),
    ({"trigger_condition": {}}, "Missing or invalid 'condition_type' in trigger_condition"),
    ({"trigger_condition": {"condition_type": 3}}, "Missing or invalid 'condition_type' in trigger_condition"),
    ({"trigger_condition": {"condition_type": "x-custom"}}, None),
    ({"trigger_condition": {"condition_type": "OnChangeTo"}}, "OnChangeTo requires 'target_value'"),
    ({"trigger_condition": {"condition_type": "EnterRange", "lower_bound": 1}}, None),
    ({"trigger_condition": {"condition_type": "LeaveRange", "lower_bound": "1", "upper_bound": 2}}, None),
    ({"trigger_condition": {"condition_type": "LeaveRange", "lower_bound": True, "upper_bound": 2}}, None),
    ({"trigger_condition": {"condition_type": "EnterRange", "lower_bound": 5, "upper_bound": 2}},
     "'lower_bound' must not exceed 'upper_bound'"),
    ({"lifetime": 0}, "Lifetime must be a positive integer (seconds)"),
    ({"lifetime": -3}, "Lifetime must be a positive integer (seconds)"),
    ({"lifetime": 1.5}, "Lifetime must be a positive integer (seconds)"),
    ({"lifetime": "60"}, "Lifetime must be a positive integer (seconds)"),
    ({"lifetime": True}, "Lifetime must be a positive integer (seconds)"),
    ({"lifetime": 2**40}, "Lifetime must be a positive integer (seconds)"),
    ({"multishot": "yes"}, "'multishot' must be a boolean"),
    ({"persistent": 1}, "'persistent' must be a boolean"),
    ({"protocol": "websocket"}, "Unsupported protocol. Supported: 'sse'"),
    ({"path": "temperature"}, None),
    ({"path": "/a~2b"}, None),
    ({"path": 7}, "Invalid JSON Pointer in 'path'"),
    ({"path": "/" + "a" * 1024}, "Path too long (max 1024)"),
    ({"resource": ...}, "resource: missing required field"),
    ({"resource": "/api/v1/apps/temp_sensor/operations"}, None),
    ({"resource": "/api/v1/apps/temp_sensor/bogus"}, None),
])
def test_bad_fields_are_invalid_parameter(client, fw, changes, message):
    before = len(fw.calls("trig_create"))
    doc = error_of(client.post(BASE, json=body(**changes)), 400, "invalid-parameter")
    if message:
        assert doc["message"] == message
    assert "parameter" in doc["parameters"]
    assert len(fw.calls("trig_create")) == before


@pytest.mark.parametrize("resource", [
    "http://robot/api/v1/apps/temp_sensor/data/x",
    "/api/v1/apps/temp_sensor/data/../../../etc/passwd",
    "/api/v1/apps/temp_sensor/data/a%zzb",
    "/api/v1/apps/temp_sensor/data/",
    "/api/v1/apps/temp_sensor/data/1abc",
    "/api/v1/apps/temp_sensor/data/x\n",
])
def test_bad_resource_uris_are_refused(client, resource):
    doc = error_of(client.post(BASE, json=body(resource=resource)), 400, "vendor-error",
                   "x-medkit-invalid-resource-uri")
    assert doc["message"].startswith("Invalid resource URI: ")


def test_a_resource_of_another_entity_is_a_mismatch(client):
    for resource in ("/api/v1/apps/controller/data/body/lights/state", "/api/v1/components/x/faults"):
        doc = error_of(client.post(BASE, json=body(resource=resource)), 400, "vendor-error",
                       "x-medkit-entity-mismatch")
        assert doc["message"] == "Resource URI must reference the same entity as the route"


def test_unknown_entities_and_triggers_are_404(client):
    error_of(client.post("/api/v1/apps/nope/triggers", json=body()), 404, "entity-not-found")
    for path in (f"{BASE}/trig_0000000000000000", f"{BASE}/nope", f"{BASE}/trig_0000000000000000/events"):
        doc = error_of(client.get(path), 404, "resource-not-found")
        assert doc["message"] == "Trigger not found"


def test_a_trigger_belongs_to_the_entity_of_its_route(client):
    made = client.post(BASE, json=body()).get_json()
    other = f"/api/v1/apps/controller/triggers/{made['id']}"
    error_of(client.get(other), 404, "resource-not-found")
    assert client.delete(other).status_code == 404
    assert client.get(f"{BASE}/{made['id']}").status_code == 200


def test_list_get_update_delete(client):
    made = client.post(BASE, json=body(lifetime=10)).get_json()
    assert made["id"] in [t["id"] for t in client.get(BASE).get_json()["items"]]
    assert client.get(f"{BASE}/{made['id']}").get_json() == made
    r = client.put(f"{BASE}/{made['id']}", json={"lifetime": 300})
    assert r.status_code == 200 and r.get_json()["lifetime"] == 300
    for bad in ({}, {"lifetime": 0}, {"lifetime": "x"}, {"lifetime": None}):
        error_of(client.put(f"{BASE}/{made['id']}", json=bad), 400, "invalid-parameter")
    assert client.delete(f"{BASE}/{made['id']}").status_code == 204
    assert client.get(f"{BASE}/{made['id']}").status_code == 404
    assert made["id"] not in [t["id"] for t in client.get(BASE).get_json()["items"]]


def test_the_trigger_cap_answers_503_with_retry_after(client, fw):
    fw.errors["trig_create"] = IpcError("triggers-full", "The gateway already holds 1000 triggers (max_triggers)",
                                        {"max_triggers": 1000})
    try:
        r = client.post(BASE, json=body())
        doc = error_of(r, 503, "service-unavailable")
        assert r.headers["Retry-After"] == "5" and doc["parameters"] == {"max_triggers": 1000}
    finally:
        del fw.errors["trig_create"]


def test_the_client_is_named_by_its_address(client, fw):
    assert client.post(BASE, json=body(), environ_base={"REMOTE_ADDR": "192.0.2.9"}).status_code == 201
    assert fw.calls("trig_create")[-1]["client"] == "192.0.2.9"


JSON = st.recursive(st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats(allow_nan=False, allow_infinity=False)
                    | st.text(max_size=20), lambda children: st.lists(children, max_size=4)
                    | st.dictionaries(st.text(max_size=8), children, max_size=4), max_leaves=12)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(resource=st.one_of(st.just(RESOURCE), st.text(max_size=80), JSON),
       condition=st.one_of(JSON, st.fixed_dictionaries(
           {"condition_type": st.sampled_from(["OnChange", "OnChangeTo", "EnterRange", "LeaveRange", "x"])},
           optional={"target_value": JSON, "lower_bound": JSON, "upper_bound": JSON})),
       path=st.one_of(st.none(), st.text(max_size=40), st.from_regex(r"\A(/[a-z0-9~]{0,4}){0,5}\Z"), JSON),
       lifetime=st.one_of(st.none(), JSON), multishot=JSON)
def test_hostile_bodies_get_the_contracts_answers(client, fw, resource, condition, path, lifetime, multishot):
    r = client.post(BASE, json={"resource": resource, "trigger_condition": condition, "path": path,
                                "lifetime": lifetime, "multishot": multishot})
    assert r.status_code in (201, 400), r.data
    doc = r.get_json()
    if r.status_code == 400:
        assert doc["error_code"] in ("invalid-parameter", "vendor-error") and doc["message"]
    else:
        assert doc["id"].startswith("trig_")
        sent = fw.calls("trig_create")[-1]
        assert isinstance(sent["path"], str) and sent["condition"]["condition_type"] in (
            "OnChange", "OnChangeTo", "EnterRange", "LeaveRange")


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(raw=st.binary(max_size=200))
def test_hostile_raw_bodies_never_500(client, raw):
    r = client.post(BASE, data=raw, content_type="application/json")
    assert r.status_code in (201, 400), r.data
    assert r.get_json()["error_code" if r.status_code == 400 else "id"]
