"""{entity}/cyclic-subscriptions: what a client sends is checked with medkit's rules and texts.

The registry behind these routes is the ROS worker's (the fake worker stands
in here); streaming, expiry and the rest through a real gateway are in
tests/system/subscriptions/test_app_streams.py.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ipc.errors import IpcError
from tests.support.fakeworker import error_of

BASE = "/api/v1/apps/temp_sensor/cyclic-subscriptions"
RESOURCE = "/api/v1/apps/temp_sensor/data/powertrain/engine/temperature"

pytestmark = pytest.mark.fakeworker(scope="module")


def body(**changes):
    out = {"resource": RESOURCE, "protocol": "sse", "interval": "normal", "duration": 60}
    out.update(changes)
    return {k: v for k, v in out.items() if v is not ...}


def test_create_answers_201_with_medkits_fields(client, fw):
    r = client.post(BASE, json=body())
    assert r.status_code == 201, r.data
    doc = r.get_json()
    assert doc["id"].startswith("sub_")
    assert doc["observed_resource"] == RESOURCE
    assert doc["event_source"] == f"{BASE}/{doc['id']}/events"
    assert doc["protocol"] == "sse" and doc["interval"] == "normal" and doc["duration"] == 60
    assert doc["expires_at"].endswith("Z") and "T" in doc["expires_at"]
    assert r.headers["Location"] == f"{BASE}/{doc['id']}"
    sent = fw.calls("sub_create")[-1]
    assert sent["topic"] == "/powertrain/engine/temperature" and sent["bytes"] == "array"


def test_the_client_is_named_by_its_address_and_a_listener_without_one_still_subscribes(client, fw):
    assert client.post(BASE, json=body(), environ_base={"REMOTE_ADDR": "192.0.2.7"}).status_code == 201
    assert fw.calls("sub_create")[-1]["client"] == "192.0.2.7"
    r = client.post(BASE, json=body(), environ_base={"REMOTE_ADDR": ""})
    assert r.status_code == 201, r.data
    assert fw.calls("sub_create")[-1]["client"] == "unknown"


def test_protocol_defaults_to_sse_and_every_topic_spelling_and_bytes_query_is_accepted(client, fw):
    for resource, mode in [
        ("/api/v1/apps/temp_sensor/data/powertrain%2Fengine%2Ftemperature", "array"),
        ("/api/v1/apps/temp_sensor/data//powertrain/engine/temperature?bytes=base64", "base64"),
        ("/api/v1/apps/temp_sensor/data/powertrain/engine/temperature?bytes=array", "array"),
    ]:
        r = client.post(BASE, json=body(protocol=..., resource=resource))
        assert r.status_code == 201, (resource, r.data)
        assert fw.calls("sub_create")[-1]["topic"] == "/powertrain/engine/temperature"
        assert fw.calls("sub_create")[-1]["bytes"] == mode


@pytest.mark.parametrize("changes, message", [
    ({"interval": "sometimes"}, "Invalid interval. Must be 'fast', 'normal', or 'slow'."),
    ({"interval": ...}, "interval: missing required field"),
    ({"duration": 0}, "Duration must be a positive integer (seconds)."),
    ({"duration": -5}, "Duration must be a positive integer (seconds)."),
    ({"duration": 1.5}, "Duration must be a positive integer (seconds)."),
    ({"duration": "60"}, "Duration must be a positive integer (seconds)."),
    ({"duration": True}, "Duration must be a positive integer (seconds)."),
    ({"duration": 3601}, "Duration must not exceed 3600 seconds."),
    ({"duration": ...}, "duration: missing required field"),
    ({"resource": ...}, "resource: missing required field"),
    ({"resource": 7}, None),
])
def test_bad_fields_are_invalid_parameter(client, fw, changes, message):
    doc = error_of(client.post(BASE, json=body(**changes)), 400, "invalid-parameter")
    if message:
        assert doc["message"] == message
    assert not fw.calls("sub_create")


def test_an_unknown_protocol_is_refused(client):
    doc = error_of(client.post(BASE, json=body(protocol="websocket")), 400, "vendor-error",
                   "x-medkit-unsupported-protocol")
    assert doc["message"] == "Protocol 'websocket' not available"


@pytest.mark.parametrize("resource", [
    "api/v1/apps/temp_sensor/data/x",                       # not a path from the root
    "http://robot/api/v1/apps/temp_sensor/data/x",          # not a path
    "/api/v2/apps/temp_sensor/data/x",
    "/api/v1/areas/temp_sensor/data/x",
    "/api/v1/apps/temp_sensor/data/../../../etc/passwd",    # traversal
    "/api/v1/apps/temp_sensor/data/a/%2e%2e/b",             # traversal, encoded
    "/api/v1/apps/temp_sensor/data/a%zzb",                  # bad percent-encoding
    "/api/v1/apps/temp_sensor/data",                        # data without a topic
    "/api/v1/apps/temp_sensor/data/",
    "/api/v1/apps/temp_sensor/data/1abc",                   # not a ROS topic name
    "/api/v1/apps/temp_sensor/data/x?bytes=hex",
    "/api/v1/apps/temp_sensor/data/x\n",
])
def test_bad_resource_uris_are_refused(client, fw, resource):
    doc = error_of(client.post(BASE, json=body(resource=resource)), 400, "vendor-error",
                   "x-medkit-invalid-resource-uri")
    assert doc["message"].startswith("Invalid resource URI: ")
    assert doc["parameters"]["parameter"] == "resource"
    assert not fw.calls("sub_create")


def test_a_resource_of_another_entity_is_a_mismatch(client):
    for resource in ("/api/v1/apps/controller/data/body/lights/state",
                     "/api/v1/components/test-robot/data/powertrain/engine/temperature"):
        doc = error_of(client.post(BASE, json=body(resource=resource)), 400, "vendor-error",
                       "x-medkit-entity-mismatch")
        assert doc["message"] == "Resource URI must reference the same entity as the route"


def test_collections_other_than_data_are_not_supported(client):
    doc = error_of(client.post(BASE, json=body(resource="/api/v1/apps/temp_sensor/faults")), 400,
                   "vendor-error", "x-medkit-collection-not-supported")
    assert doc["message"] == "Collection 'faults' not supported for apps"
    assert doc["parameters"] == {"collection": "faults", "entity_type": "apps"}


def test_bodies_that_are_not_json_objects(client):
    error_of(client.post(BASE, data=b"{not json", content_type="application/json"), 400, "invalid-request")
    error_of(client.post(BASE, json=[1, 2]), 400, "invalid-request")


def test_unknown_entities_and_subscriptions_are_404(client):
    error_of(client.post("/api/v1/apps/nobody/cyclic-subscriptions", json=body()), 404, "entity-not-found")
    error_of(client.get("/api/v1/apps/nobody/cyclic-subscriptions"), 404, "entity-not-found")
    for path in ("/sub_00000000000000ff", "/sub_00000000000000ff/events", "/not-an-id"):
        doc = error_of(client.get(BASE + path), 404, "resource-not-found")
        assert doc["message"] == "Subscription not found"
    error_of(client.delete(BASE + "/sub_00000000000000ff"), 404, "resource-not-found")
    error_of(client.put(BASE + "/sub_00000000000000ff", json={"interval": "fast"}), 404, "resource-not-found")


def test_a_subscription_belongs_to_the_entity_of_its_route(client):
    sub = client.post(BASE, json=body()).get_json()
    other = "/api/v1/apps/controller/cyclic-subscriptions"
    error_of(client.get(f"{other}/{sub['id']}"), 404, "resource-not-found")
    error_of(client.delete(f"{other}/{sub['id']}"), 404, "resource-not-found")
    assert client.get(other).get_json() == {"items": []}
    assert [s["id"] for s in client.get(BASE).get_json()["items"]] == [sub["id"]]


def test_list_get_update_delete(client):
    sub = client.post(BASE, json=body()).get_json()
    assert client.get(f"{BASE}/{sub['id']}").get_json() == sub
    r = client.put(f"{BASE}/{sub['id']}", json={"interval": "fast"})
    assert r.status_code == 200 and r.get_json()["interval"] == "fast"
    error_of(client.put(f"{BASE}/{sub['id']}", json={"duration": 0}), 400, "invalid-parameter")
    error_of(client.put(f"{BASE}/{sub['id']}", json={"interval": "never"}), 400, "invalid-parameter")
    r = client.delete(f"{BASE}/{sub['id']}")
    assert r.status_code == 204 and r.data == b""
    error_of(client.get(f"{BASE}/{sub['id']}"), 404, "resource-not-found")


def test_numbers_json_can_hold_but_orjson_cannot_write_are_still_answered(client):
    """A duration of -2**70 is refused with a 400 that echoes it, not a 500 from writing it."""
    for path, method in ((BASE, "post"), (BASE + "/sub_0000000000000001", "put")):
        r = getattr(client, method)(path, data=b'{"interval": "fast", "resource": "x", '
                                              b'"duration": -1180591620717411303424}',
                                    content_type="application/json")
        doc = error_of(r, 400, "invalid-parameter")
        assert doc["parameters"]["value"] == "-1180591620717411303424"


def test_the_subscription_cap_answers_503_with_retry_after(client, fw):
    fw.errors["sub_create"] = IpcError("subscriptions-full", "The gateway already holds 1000 cyclic "
                                       "subscriptions (max_subscriptions); delete one or retry later",
                                       {"max_subscriptions": 1000})
    r = client.post(BASE, json=body())
    error_of(r, 503, "service-unavailable")
    assert r.headers["Retry-After"].isdigit()


JSON = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(),
                    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(), inner, max_size=4),
                    max_leaves=12)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(resource=st.one_of(st.text(max_size=200), st.builds(lambda tail: "/api/v1/apps/temp_sensor/" + tail,
                                                            st.text(max_size=100)), JSON),
       interval=st.one_of(st.sampled_from(["fast", "normal", "slow"]), JSON),
       duration=st.one_of(st.integers(-10, 5000), st.integers(-2**80, 2**80), JSON),
       protocol=st.one_of(st.just("sse"), JSON))
def test_hostile_bodies_get_the_contracts_answers(client, fw, resource, interval, duration, protocol):
    r = client.post(BASE, json={"resource": resource, "interval": interval, "duration": duration,
                                "protocol": protocol})
    assert r.status_code in (201, 400), r.data
    doc = r.get_json()
    if r.status_code == 400:
        assert doc["error_code"] in ("invalid-parameter", "invalid-request", "vendor-error")
        assert isinstance(doc["message"], str)
    else:
        assert fw.calls("sub_create")[-1]["topic"].startswith("/")


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(raw=st.binary(max_size=300))
def test_hostile_raw_bodies_never_500(client, raw):
    r = client.post(BASE, data=raw, content_type="application/json")
    assert r.status_code in (201, 400), r.data
