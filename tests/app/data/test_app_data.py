"""GET {entity}/data and {entity}/data/{data_id} (app/data/routes.py) against a fake ROS worker."""

from __future__ import annotations

import time

import orjson
import pytest

from ipc.errors import IpcError
from tests.support.fakeworker import data_sample, error_of, make_app, metadata_sample, node

TEMP = "/powertrain/engine/temperature"
TEMP_TYPE = "sensor_msgs/msg/Temperature"
TEMP_DATA = {"header": {"stamp": {"sec": 1769955040, "nanosec": 286555163}, "frame_id": "engine"},
             "temperature": 93.5, "variance": 0.5}
TEMP_INFO = {"schema": {"type": "object", "properties": {"temperature": {"type": "number"}}},
             "default_value": {"temperature": 0.0, "variance": 0.0}}

pytestmark = pytest.mark.fakeworker(samples={TEMP: data_sample(TEMP, TEMP_TYPE, TEMP_DATA)},
                                    type_infos={TEMP_TYPE: TEMP_INFO}, sample_timeout=0.5)


# ------------------------------------------------------------------ GET {entity}/data


def test_app_data_items(client):
    r = client.get("/api/v1/apps/temp_sensor/data")
    assert r.status_code == 200
    body = r.get_json()
    by_id = {i["id"]: i for i in body["items"]}
    assert set(by_id) == {TEMP, "/rosout", "/parameter_events"}
    assert by_id[TEMP] == {"id": TEMP, "name": TEMP, "category": "currentData",
                           "x-medkit": {"ros2": {"topic": TEMP, "type": TEMP_TYPE, "direction": "publish"},
                                        "type_info": TEMP_INFO}}
    assert by_id["/parameter_events"]["x-medkit"]["ros2"]["direction"] == "subscribe"
    assert "type_info" not in by_id["/rosout"]["x-medkit"]  # type not installed in the fake
    assert body["x-medkit"] == {"entity_id": "temp_sensor", "total_count": 3}


def test_data_listing_samples_nothing_and_caches_type_info(client, fw):
    for _ in range(3):
        assert client.get("/api/v1/apps/temp_sensor/data").status_code == 200
    assert fw.calls("sample") == []
    asked = [a["type"] for a in fw.calls("type_info")]
    assert asked.count(TEMP_TYPE) == 1  # cached per type
    assert asked.count("rcl_interfaces/msg/Log") == 1  # "not installed" is cached too


@pytest.mark.parametrize("path, level", [("/api/v1/components/test-robot/data", "component"),
                                         ("/api/v1/functions/body/data", "function")])
def test_aggregated_data_items(client, path, level):
    body = client.get(path).get_json()
    ids = [i["id"] for i in body["items"]]
    assert len(ids) == len(set(ids))
    assert "/rosout" in ids and "/body/lights/cmd" in ids
    rosout = next(i for i in body["items"] if i["id"] == "/rosout")
    assert rosout["x-medkit"]["member_ids"]
    cmd = next(i for i in body["items"] if i["id"] == "/body/lights/cmd")
    assert cmd["x-medkit"]["member_ids"] == ["controller"]
    assert cmd["x-medkit"]["ros2"]["direction"] == "subscribe"
    ext = body["x-medkit"]
    assert ext["aggregated"] is True and ext["aggregation_level"] == level
    assert "controller" in ext["aggregation_sources"]
    assert ext["total_count"] == len(ids)


def test_type_info_trouble_leaves_it_out(fw):
    fw.silent.add("type_info")
    client = make_app(fw, ipc_timeout=0.3).test_client()
    r = client.get("/api/v1/apps/temp_sensor/data")
    assert r.status_code == 200
    assert all("type_info" not in i["x-medkit"] for i in r.get_json()["items"])


# ------------------------------------------------------------------ GET one sample


def test_sample(client, fw):
    r = client.get("/api/v1/apps/temp_sensor/data/powertrain/engine/temperature")
    assert r.status_code == 200
    assert r.headers["Content-Type"] == "application/json"
    assert r.get_json() == {
        "id": TEMP, "data": TEMP_DATA,
        "x-medkit": {"entity_id": "temp_sensor", "timestamp": 1769955039964403368,
                     "ros2": {"topic": TEMP, "type": TEMP_TYPE},
                     "publisher_count": 1, "subscriber_count": 0, "status": "data",
                     "type_info": TEMP_INFO}}
    (args,) = fw.calls("sample")
    assert args == {"topic": TEMP, "timeout_ms": 500}
    # IPC deadline = sample timeout + a margin
    assert 1500 <= fw.deadlines("sample")[0] <= 2000


def test_type_info_of_a_read_is_asked_once_per_type(client, fw):
    """The warm path adds no round trip: the type_info cache the listing fills serves every read."""
    for _ in range(5):
        assert client.get("/api/v1/apps/temp_sensor/data" + TEMP).get_json()["x-medkit"]["type_info"] == TEMP_INFO
    assert fw.calls("type_info") == [{"type": TEMP_TYPE}]
    assert len(fw.calls("sample")) == 5


def test_type_info_is_left_out_when_unknown_or_unavailable(client, fw):
    fw.samples["/x"] = data_sample("/x", "pkg/msg/NotInstalled", {"a": 1})
    ext = client.get("/api/v1/apps/temp_sensor/data/x").get_json()["x-medkit"]
    assert "type_info" not in ext and ext["status"] == "data"
    fw.samples["/y"] = data_sample("/y", "pkg/msg/Slow", {"a": 1})
    fw.errors["type_info"] = IpcError("deadline-exceeded", "too slow")
    r = client.get("/api/v1/apps/temp_sensor/data/y")
    assert r.status_code == 200 and "type_info" not in r.get_json()["x-medkit"]
    r = client.get("/api/v1/apps/temp_sensor/data/no/type")   # metadata only, no type: nothing to ask
    assert r.status_code == 200 and "type_info" not in r.get_json()["x-medkit"]


def test_sample_bytes_are_spliced_unchanged(client, fw):
    raw = b'{"data":1.0,"text":"123","empty":[],"nested":{"a":[1,2,255]},"big":18446744073709551615}'
    reply = data_sample("/x", "pkg/msg/T", {})
    reply["data_json"] = raw
    fw.samples["/x"] = reply
    r = client.get("/api/v1/apps/temp_sensor/data/x")
    assert r.status_code == 200
    assert b'"data":' + raw + b',"x-medkit":' in r.data
    data = r.get_json()["data"]
    assert data["data"] == 1.0 and isinstance(data["data"], float)
    assert data["text"] == "123" and data["empty"] == [] and data["big"] == 18446744073709551615


@pytest.mark.parametrize("path", [
    "powertrain%2Fengine%2Ftemperature",
    "powertrain/engine/temperature",
    "/powertrain/engine/temperature",
    "%2Fpowertrain%2Fengine%2Ftemperature",
    "powertrain%2fengine/temperature",
])
def test_data_id_spellings_name_one_topic(client, fw, path):
    r = client.get("/api/v1/apps/temp_sensor/data/" + path)
    assert r.status_code == 200, r.data
    assert r.get_json()["id"] == TEMP
    assert fw.calls("sample")[-1]["topic"] == TEMP


@pytest.mark.parametrize("path, detail", [
    ("a%zzb", "percent-encoding"),
    ("a%2", "percent-encoding"),
    ("a%00b", "NUL"),
    ("a%FFb", "UTF-8"),
    ("", "empty"),
    ("a/", "not a valid ROS topic"),
    ("a//b", "not a valid ROS topic"),
    ("1abc", "not a valid ROS topic"),
    ("a-b", "not a valid ROS topic"),
    ("a%20b", "not a valid ROS topic"),
    ("a%0Ab", "not a valid ROS topic"),
    ("a%252Fb", "not a valid ROS topic"),
    ("x" * 300, "longer than"),
])
@pytest.mark.parametrize("method", ["GET", "PUT"])
def test_invalid_topic_is_400_before_the_ros_worker(fw, path, detail, method):
    client = make_app(fw, allow_publish=True).test_client()
    r = client.open("/api/v1/apps/temp_sensor/data/" + path, method=method,
                    json={"type": "std_msgs/msg/Bool", "data": {"data": True}})
    assert r.status_code == 400, r.data
    body = r.get_json()
    assert body["error_code"] == "invalid-parameter"
    assert body["message"] == "Invalid topic name"
    assert detail in body["parameters"]["details"]
    assert [c for c, _, _ in fw.requests if c in ("sample", "publish", "graph")] == []


def test_entity_must_exist_but_topic_is_not_checked_against_it(client, fw):
    fw.samples["/chassis/brakes/pressure"] = data_sample("/chassis/brakes/pressure", "std_msgs/msg/Float32",
                                                         {"data": 7.5})
    r = client.get("/api/v1/apps/temp_sensor/data/chassis/brakes/pressure")
    assert r.status_code == 200 and r.get_json()["data"] == {"data": 7.5}
    r = client.get("/api/v1/functions/body/data/chassis/brakes/pressure")
    assert r.status_code == 200 and r.get_json()["x-medkit"]["entity_id"] == "body"
    r = client.get("/api/v1/apps/ghost/data/chassis/brakes/pressure")
    assert r.status_code == 404 and r.get_json()["error_code"] == "entity-not-found"
    assert len(fw.calls("sample")) == 2


@pytest.mark.parametrize("reason", ["not-in-graph", "no-publishers", "timeout", "unsupported-type"])
def test_metadata_only(client, fw, reason):
    fw.samples["/quiet"] = metadata_sample("/quiet", "std_msgs/msg/Bool" if reason != "not-in-graph" else None,
                                           reason=reason)
    before = time.time_ns()
    r = client.get("/api/v1/apps/temp_sensor/data/quiet")
    assert r.status_code == 200
    body = r.get_json()
    assert body["data"] == {}
    ext = body["x-medkit"]
    assert ext["status"] == "metadata_only" and ext["reason"] == reason
    assert isinstance(ext["timestamp"], int) and ext["timestamp"] >= before - 10**9
    if reason == "not-in-graph":
        assert "type" not in ext["ros2"]


def test_bytes_base64_is_passed_to_the_worker(client, fw):
    reply = data_sample("/img", "sensor_msgs/msg/Image", {"data": "AAEC"})
    fw.samples["/img"] = reply
    r = client.get("/api/v1/apps/temp_sensor/data/img?bytes=base64")
    assert r.status_code == 200 and r.get_json()["data"] == {"data": "AAEC"}
    assert fw.calls("sample")[-1] == {"topic": "/img", "timeout_ms": 500, "bytes": "base64"}
    assert client.get("/api/v1/apps/temp_sensor/data/img?bytes=array").status_code == 200
    assert "bytes" not in fw.calls("sample")[-1]


def test_bad_bytes_parameter(client, fw):
    r = client.get("/api/v1/apps/temp_sensor/data/img?bytes=hex")
    assert r.status_code == 400
    body = r.get_json()
    assert body["error_code"] == "invalid-parameter" and body["parameters"]["bytes"] == "hex"
    assert fw.calls("sample") == []


# ------------------------------------------------------------------ errors of the ROS worker


def test_silent_worker_gives_504_not_a_hang(fw):
    fw.silent.add("sample")
    client = make_app(fw, sample_timeout=0.1).test_client()
    start = time.monotonic()
    r = client.get("/api/v1/apps/temp_sensor/data/powertrain/engine/temperature")
    assert time.monotonic() - start < 30  # a hang would be caught by pytest-timeout anyway
    assert r.status_code == 504
    body = r.get_json()
    assert body["error_code"] == "not-responding"
    assert body["parameters"]["entity_id"] == "temp_sensor"


def test_worker_gone_after_discovery_gives_503(fw):
    client = make_app(fw, SOVD_GRAPH_REFRESH_S=600.0).test_client()
    assert client.get("/api/v1/apps").status_code == 200  # graph cached
    fw.stop()
    r = client.get("/api/v1/apps/temp_sensor/data/powertrain/engine/temperature")
    error_of(r, 503, "vendor-error", "x-medkit-ros-worker-unavailable")
    assert r.headers["Retry-After"] == "2"


def test_cold_wait_cap_exceeded(client, fw):
    fw.errors["sample"] = IpcError("cold-wait-cap-exceeded", "cap", {"topic": TEMP, "cold_wait_cap": 4})
    r = client.get("/api/v1/apps/temp_sensor/data/powertrain%2Fengine%2Ftemperature")
    body = error_of(r, 503, "vendor-error", "x-medkit-cold-wait-cap-exceeded")
    assert r.headers["Retry-After"] == "1"
    assert "retry" in body["message"].lower() and "backoff" in body["message"]
    assert body["parameters"] == {"topic": TEMP, "cold_wait_cap": 4, "entity_id": "temp_sensor",
                                  "topic_name": "powertrain/engine/temperature"}


@pytest.mark.parametrize("code, status, error_code, vendor_code, retry", [
    ("backpressure", 503, "vendor-error", "x-medkit-ros-worker-backpressure", "1"),
    ("shutdown", 503, "vendor-error", "x-medkit-gateway-shutdown", "2"),
    ("subscribe-failed", 500, "vendor-error", "x-medkit-subscribe-failed", None),
    ("deadline-exceeded", 504, "not-responding", None, None),
    ("invalid-topic", 400, "invalid-parameter", None, None),
    ("internal", 500, "internal-error", None, None),
    ("something-new", 500, "internal-error", None, None),
])
def test_worker_errors_map_through_the_table(client, fw, code, status, error_code, vendor_code, retry):
    fw.errors["sample"] = IpcError(code, "worker says no", {"topic": TEMP})
    r = client.get("/api/v1/apps/temp_sensor/data/powertrain/engine/temperature")
    assert r.status_code == status
    body = r.get_json()
    assert body["error_code"] == error_code
    assert body.get("vendor_code") == vendor_code
    assert body["message"] == "worker says no"
    assert r.headers.get("Retry-After") == retry


def test_data_categories_and_groups_are_not_implemented(client, fw):
    for what in ("data-categories", "data-groups"):
        r = client.get(f"/api/v1/apps/temp_sensor/{what}")
        assert r.status_code == 501
        body = r.get_json()
        assert body["error_code"] == "not-implemented"
        assert body["parameters"] == {"feature": what}


def test_many_nodes_sample_body_is_valid_json(fw):
    fw.set_graph([node(f"/ns{i}/n{i}") for i in range(200)])
    fw.samples["/t"] = data_sample("/t", "std_msgs/msg/String", {"data": "é\u2028\"quoted\""})
    client = make_app(fw).test_client()
    r = client.get("/api/v1/apps/n150/data/t")
    assert orjson.loads(r.data)["data"]["data"] == "é\u2028\"quoted\""
