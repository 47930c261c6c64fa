"""End to end: the real ``sovd-gateway`` (supervisor, ROS worker, gunicorn) and real ROS nodes.

Nothing of ours is mocked here.  The ROS nodes run in their own processes
(``tests/support/rospub.py``) in this session's private ROS domain.
"""

from __future__ import annotations

import http.client
import json
import math
import os
import re
import signal

import psutil
import pytest
import requests

from app.core import unimplemented
from app.core.entities import PARAM_NAMES, host_component_id
from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from tests.support import floats
from tests.support.rospub import RosNode, publisher

TEMP = "/powertrain/engine/temperature"
PRESSURE = "/chassis/brakes/pressure"
TOKEN = "e2e-token-0123456789abcdef"
HOST_ID = host_component_id(os.uname().nodename)


@pytest.fixture(scope="module")
def robot():
    nodes = [
        publisher("temp_sensor", "temperature", "sensor_msgs/msg/Temperature",
                  {"temperature": 93.5, "variance": 0.5, "header": {"frame_id": "engine"}},
                  namespace="/powertrain/engine"),
        publisher("pressure_sensor", "pressure", "std_msgs/msg/Float32", {"data": 7.25},
                  namespace="/chassis/brakes"),
        RosNode({"node": "controller", "namespace": "/body/lights",
                 "publish": [{"topic": "state", "type": "std_msgs/msg/Bool", "rate": 5, "value": {"data": True}}],
                 "subscribe": [{"topic": "cmd", "type": "std_msgs/msg/Bool", "echo": True}]}),
        RosNode({"node": "driver", "namespace": "/left/wheel"}),
        RosNode({"node": "driver", "namespace": "/right/wheel"}),
    ]
    yield {"temp": nodes[0], "pressure": nodes[1], "controller": nodes[2]}
    for n in nodes:
        n.stop()


@pytest.fixture(scope="module")
def gw(robot, gateway):
    return gateway("--allow-publish", "--api-token", TOKEN, "--sample-timeout", "3")


def app_ids(gw) -> list[str]:
    r = gw.get("/apps")
    assert r.status_code == 200, r.text
    return [i["id"] for i in r.json()["items"]]


def settled(predicate, timeout: float = 30, message: str = "condition", times: int = 5):
    """Poll until ``predicate`` holds ``times`` times in a row, 0.1 s apart.

    Each HTTP worker process refreshes its graph cache at most every 0.2 s, so
    one answer that shows a change may come from a fresher process than the
    next; holding for half a second means every process has caught up.
    """
    streak = {"n": 0, "value": None}

    def check():
        value = predicate()
        streak["n"] = streak["n"] + 1 if value else 0
        streak["value"] = value
        return streak["n"] >= times

    poll_until(check, timeout, interval=0.1, message=message)
    return streak["value"]


def wait_for_apps(gw, wanted: set[str], timeout: float = 30) -> list[str]:
    return settled(lambda: wanted <= set(ids := app_ids(gw)) and ids, timeout, message=f"apps {sorted(wanted)}")


def sample(gw, path: str) -> dict:
    r = gw.get(path)
    assert r.status_code == 200, r.text
    return r.json()


def wait_for_data(gw, path: str, timeout: float = 30) -> dict:
    return poll_until(lambda: (b := sample(gw, path))["x-medkit"]["status"] == "data" and b, timeout,
                      message=f"data at {path}")


def raw_get(gw, path: str) -> tuple[int, dict]:
    """GET with the path sent exactly as written (no client-side re-quoting)."""
    conn = http.client.HTTPConnection("127.0.0.1", gw.port, timeout=15)
    try:
        conn.request("GET", path)
        resp = conn.getresponse()
        return resp.status, json.loads(resp.read())
    finally:
        conn.close()


# ------------------------------------------------------------------ discovery


def test_entities_follow_the_ros_graph(gw):
    ids = wait_for_apps(gw, {"temp_sensor", "pressure_sensor", "controller", "left_wheel_driver",
                             "right_wheel_driver"})
    assert not any(i.startswith("sovd_gateway") for i in ids)  # the gateway's own node is left out
    comps = gw.get("/components").json()
    assert [c["id"] for c in comps["items"]] == [HOST_ID]
    assert gw.get("/areas").json() == {"items": [], "x-medkit": {"total_count": 0}}
    funcs = {f["id"]: f for f in gw.get("/functions").json()["items"]}
    assert {"powertrain", "chassis", "body", "left", "right"} <= set(funcs)
    assert funcs["powertrain"]["hosts"] == ["temp_sensor"]
    detail = gw.get("/apps/temp_sensor").json()
    assert detail["x-medkit"]["ros2"]["node"] == "/powertrain/engine/temp_sensor"
    assert detail["is-located-on"] == f"/api/v1/components/{HOST_ID}"
    assert [c["name"] for c in detail["capabilities"]] == ["status", "data", "operations", "configurations",
                                                           "faults", "logs", "triggers", "is-located-on", "belongs-to"]
    located = gw.get("/apps/temp_sensor/is-located-on").json()
    assert located["items"][0]["id"] == HOST_ID


def test_id_rules(gw):
    wait_for_apps(gw, {"temp_sensor"})
    r = gw.get("/components/temp_sensor")
    assert r.status_code == 400
    assert r.json()["parameters"]["expected_type"] == "Component"
    assert r.json()["parameters"]["actual_type"] == "App"
    assert r.json()["message"] == "Invalid entity type for route: expected Component, got App"
    assert gw.get("/apps/no_such_app").status_code == 404
    assert gw.get("/apps/bad.id").json()["message"] == "Invalid entity ID"


# ------------------------------------------------------------------ relations (medkit's HATEOAS)
APPS = {"temp_sensor", "pressure_sensor", "controller", "left_wheel_driver", "right_wheel_driver"}


def relation(gw, path: str) -> dict:
    r = gw.get(path)
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["x-medkit"]["total_count"] == len(body["items"])
    assert body["_links"]["self"] == "/api/v1" + path
    for item in body["items"]:
        assert {"id", "name", "href"} <= set(item) and item["href"].endswith("/" + item["id"])
    return body


def test_relations_follow_the_ros_graph(gw):
    wait_for_apps(gw, APPS)
    hosts = relation(gw, f"/components/{HOST_ID}/hosts")
    assert APPS <= {i["id"] for i in hosts["items"]}
    assert all(i["href"].startswith("/api/v1/apps/") for i in hosts["items"])
    assert hosts["_links"]["component"] == f"/api/v1/components/{HOST_ID}"
    func = relation(gw, "/functions/powertrain/hosts")
    assert [i["id"] for i in func["items"]] == ["temp_sensor"]
    assert func["_links"]["function"] == "/api/v1/functions/powertrain"
    assert [i["id"] for i in relation(gw, "/functions/left/hosts")["items"]] == ["left_wheel_driver"]
    located = relation(gw, "/apps/temp_sensor/is-located-on")
    assert [(i["id"], i["href"]) for i in located["items"]] == [(HOST_ID, f"/api/v1/components/{HOST_ID}")]
    assert located["_links"]["app"] == "/api/v1/apps/temp_sensor"
    for path, owner in ((f"/components/{HOST_ID}/subcomponents", "parent"),
                        (f"/components/{HOST_ID}/depends-on", "component"),
                        ("/apps/temp_sensor/belongs-to", "app"), ("/apps/controller/depends-on", "app")):
        body = relation(gw, path)
        assert body["items"] == [] and body["x-medkit"] == {"total_count": 0}, path
        assert owner in body["_links"], path


def test_every_link_of_every_entity_answers(gw):
    """A client that follows every URI a detail advertises never meets a 404.

    Each detail links operations, configurations, faults, logs and triggers (medkit's URIs and capabilities), and
    each of those answers 200 through the ROS worker.
    """
    wait_for_apps(gw, APPS)
    followed = 0
    resources = ("operations", "configurations", "faults", "logs", "triggers")
    for collection in ("components", "apps", "functions"):
        for item in gw.get(f"/{collection}").json()["items"]:
            detail = gw.get(f"/{collection}/{item['id']}").json()
            base = f"/api/v1/{collection}/{item['id']}"
            caps = {c["name"]: c["href"] for c in detail["capabilities"]}
            for name in resources:
                assert detail[name] == caps[name] == f"{base}/{name}", (collection, item["id"], name)
            uris = {v for v in detail.values() if isinstance(v, str) and v.startswith("/api/v1/")}
            uris |= {c["href"] for c in detail["capabilities"]} | set(detail["_links"].values())
            for uri in uris:
                r = gw.get(uri[len("/api/v1"):])
                assert r.status_code == 200, (uri, r.text)
                if uri.rsplit("/", 1)[1] in resources:
                    assert isinstance(r.json()["items"], list), (uri, r.text)
                followed += 1
    assert followed > 30


def not_found(message: str, **parameters: str) -> dict:
    return {"error_code": "entity-not-found", "message": message, "parameters": parameters}


@pytest.mark.parametrize("path, status, body", [
    ("/components/nope/hosts", 404, not_found("Component not found", component_id="nope")),
    ("/components/temp_sensor/subcomponents", 404, not_found("Component not found", component_id="temp_sensor")),
    ("/functions/nope/hosts", 404, not_found("Function not found", function_id="nope")),
    ("/apps/nope/belongs-to", 404, not_found("Entity not found", entity_id="nope")),
    ("/apps/powertrain/depends-on", 400,
     {"error_code": "invalid-parameter", "message": "Invalid entity type for route: expected App, got Function",
      "parameters": {"entity_id": "powertrain", "expected_type": "App", "actual_type": "Function"}}),
    ("/areas/nope", 404, not_found("Entity not found", entity_id="nope")),
    *[(f"/areas/nope/{relation}", 404, not_found("Area not found", area_id="nope"))
      for relation in ("components", "contains", "subareas")],
    ("/areas/area;drop/components", 400,
     {"error_code": "invalid-parameter", "message": "Invalid area ID",
      "parameters": {"area_id": "area;drop", "details": "Entity ID contains invalid character: ';'. "
                                                        "Only alphanumeric, underscore and hyphen are allowed"}}),
    ("/components/a%20b/hosts", 400,
     {"error_code": "invalid-parameter", "message": "Invalid component ID",
      "parameters": {"component_id": "a b", "details": "Entity ID contains invalid character: ' '. "
                                                       "Only alphanumeric, underscore and hyphen are allowed"}}),
])
def test_relation_errors_through_gunicorn(gw, path, status, body):
    wait_for_apps(gw, {"temp_sensor"})
    r = gw.get(path)
    assert r.status_code == status and r.headers["Content-Type"] == "application/json"
    assert r.json() == body


def test_scoped_docs_through_gunicorn(gw):
    wait_for_apps(gw, {"temp_sensor"})
    whole = gw.get("/docs").json()
    apps = gw.get("/apps/docs").json()
    assert set(apps["paths"]) == {p for p in whole["paths"] if p == "/apps" or p.startswith("/apps/")}
    one = gw.get("/apps/temp_sensor/docs").json()
    assert "/apps/temp_sensor/is-located-on" in one["paths"]
    assert all(p.startswith("/apps/temp_sensor") for p in one["paths"])
    data = gw.get("/apps/temp_sensor/data/docs").json()
    (param,) = [p for p in data["paths"]["/apps/temp_sensor/data/{data_id}"]["get"]["parameters"]
                if p["name"] == "data_id"]
    assert TEMP in param["examples"]
    r = gw.get("/apps/no_such_app/docs")
    assert r.status_code == 404
    assert r.json()["message"] == "No capability description available for the requested path"
    assert "GET /api/v1/components/{component_id}/hosts" in gw.get("/").json()["endpoints"]


def test_data_items_of_an_app(gw):
    wait_for_apps(gw, {"temp_sensor"})
    body = gw.get("/apps/temp_sensor/data").json()
    items = {i["id"]: i for i in body["items"]}
    assert {TEMP, "/rosout", "/parameter_events"} <= set(items)
    temp = items[TEMP]["x-medkit"]
    assert temp["ros2"] == {"topic": TEMP, "type": "sensor_msgs/msg/Temperature", "direction": "publish"}
    assert temp["type_info"]["schema"]["type"] == "object"
    assert "temperature" in temp["type_info"]["default_value"]
    comp = gw.get(f"/components/{HOST_ID}/data").json()
    assert comp["x-medkit"]["aggregated"] is True
    cmd = next(i for i in comp["items"] if i["id"] == "/body/lights/cmd")
    assert cmd["x-medkit"]["member_ids"] == ["controller"]
    assert cmd["x-medkit"]["ros2"]["direction"] == "subscribe"


def test_routes_not_served_here_are_501_not_404(gw):
    """medkit's routes without a provider here answer 501 whatever the ids; a wrong id elsewhere stays 404."""
    wait_for_apps(gw, {"temp_sensor"})
    ids = {"apps": "temp_sensor", "components": HOST_ID, "areas": "nope", "functions": "powertrain"}
    auth = {"Authorization": f"Bearer {TOKEN}"}
    for route, path, collection in unimplemented.paths():
        for real in (True, False):
            concrete = path
            if collection:
                concrete = path.replace("{" + PARAM_NAMES[collection] + "}", ids[collection] if real else "no_such")
            concrete = re.sub(r"\{[^}]+\}", "x1", concrete)
            r = requests.request(route.method, gw.api + concrete, headers=auth, timeout=15)
            assert r.status_code == 501, (route.method, concrete, r.text)
            assert r.json() == {"error_code": "not-implemented",
                                "message": unimplemented.FEATURES[route.feature].message,
                                "parameters": {"feature": route.feature}}, concrete
    caps = gw.get("/").json()["capabilities"]
    assert [name for name in ("scripts", "lifecycle", "updates") if caps[name]] == []
    assert caps["locking"] is True   # locks are served (issue 31), on by default as in medkit
    assert caps["bulk_data"] is True  # served (issue 32, app/bulk_data/)
    r = gw.get("/apps/temp_sensor/no-such-collection")
    assert r.status_code == 404 and r.json()["error_code"] == "resource-not-found"
    r = requests.post(gw.api + "/areas/nope/bulk-data/x1", headers=auth, timeout=15)   # (a write: the token first)
    assert r.status_code == 405, r.text   # as medkit: bulk data is uploaded to components and apps only


# ------------------------------------------------------------------ samples


def test_sample_of_a_live_topic(gw):
    wait_for_apps(gw, {"temp_sensor"})
    body = wait_for_data(gw, "/apps/temp_sensor/data/powertrain/engine/temperature")
    assert body["id"] == TEMP, body
    data = body["data"]
    assert data["temperature"] == 93.5 and isinstance(data["temperature"], float), body
    assert data["header"]["frame_id"] == "engine", body
    assert set(data["header"]["stamp"]) == {"sec", "nanosec"}, body
    ext = body["x-medkit"]
    assert ext["entity_id"] == "temp_sensor" and ext["publisher_count"] >= 1, body
    assert ext["ros2"] == {"topic": TEMP, "type": "sensor_msgs/msg/Temperature"}, body
    assert isinstance(ext["timestamp"], int), body


@pytest.mark.parametrize("path", [
    "/api/v1/functions/chassis/data/chassis%2Fbrakes%2Fpressure",
    "/api/v1/functions/chassis/data/chassis/brakes/pressure",
    "/api/v1/functions/chassis/data//chassis/brakes/pressure",
])
def test_data_id_spellings_through_gunicorn(gw, path):
    wait_for_apps(gw, {"pressure_sensor"})
    body = poll_until(lambda: (b := raw_get(gw, path))[0] == 200 and b[1]["x-medkit"]["status"] == "data"
                      and b[1], 30, message=path)
    assert body["id"] == PRESSURE and body["data"] == {"data": 7.25}


@pytest.mark.parametrize("path", ["/api/v1/functions/chassis/data/a%zz", "/api/v1/functions/chassis/data/a%00b",
                                  "/api/v1/functions/chassis/data/1abc"])
def test_invalid_topics_through_gunicorn(gw, path):
    wait_for_apps(gw, {"pressure_sensor"})
    status, body = raw_get(gw, path)
    assert status == 400 and body["error_code"] == "invalid-parameter"


def test_names_the_middleware_refuses_are_400_without_a_traceback(gw):
    """rmw caps a topic name at 247 characters; longer ones once escaped from rclpy as a 500."""
    wait_for_apps(gw, {"controller"})
    auth = {"Authorization": f"Bearer {TOKEN}"}
    body = {"type": "std_msgs/msg/Bool", "data": {"data": True}}
    before = len(gw.output)
    for length in range(248, 256):  # the fully qualified name, leading "/" included
        data_id = "a" * (length - 1)
        for r in (gw.get(f"/apps/controller/data/{data_id}"),
                  gw.get(f"/apps/controller/data//{data_id}"),
                  gw.put(f"/apps/controller/data/{data_id}", json=body, headers=auth),
                  gw.put(f"/functions/body/data/body/{'b' * (length - 6)}", json=body, headers=auth)):
            assert r.status_code == 400, (length, r.request.method, r.text)
            assert r.json()["error_code"] == "invalid-parameter", r.text
            assert "247" in r.json()["parameters"]["details"], r.text
    longest = "a" * 246  # /aaa...: 247 characters, valid
    r = gw.get(f"/apps/controller/data/{longest}")
    assert r.status_code == 200 and r.json()["x-medkit"]["status"] == "metadata_only", r.text
    r = gw.put(f"/apps/controller/data/{longest}", json=body, headers=auth)
    assert r.status_code == 200, r.text
    assert gw.get("/health").json()["x-medkit-subscription-executor"]["worker_alive"] is True
    logged = "\n".join(gw.output[before:])
    assert "Traceback" not in logged and "ERROR" not in logged, logged[-3000:]


def test_a_read_carries_the_type_info_the_listing_has(gw):
    """medkit sends ``x-medkit.type_info`` in every data read (``build_read_response``)."""
    wait_for_data(gw, f"/apps/temp_sensor/data{TEMP}")
    listed = next(i for i in gw.get("/apps/temp_sensor/data").json()["items"] if i["id"] == TEMP)
    for _ in range(3):  # the first read of the type in an HTTP worker asks the ROS worker, the rest hit its cache
        ext = sample(gw, f"/apps/temp_sensor/data{TEMP}")["x-medkit"]
        assert ext["type_info"] == listed["x-medkit"]["type_info"]
        assert ext["type_info"]["default_value"]["temperature"] == 0.0


def test_a_command_input_without_publishers_reads_with_its_type(gw):
    """A topic with subscribers only (the controller's command input) says what to PUT to it."""
    wait_for_apps(gw, {"controller"})
    ext = poll_until(lambda: (e := sample(gw, "/apps/controller/data/body/lights/cmd")["x-medkit"])
                     ["subscriber_count"] >= 1 and e, 15, message="the subscriber of /body/lights/cmd")
    assert ext["status"] == "metadata_only" and ext["reason"] == "no-publishers"
    assert ext["ros2"] == {"topic": "/body/lights/cmd", "type": "std_msgs/msg/Bool"}
    assert ext["type_info"]["default_value"] == {"data": False}


def test_topic_not_in_graph_is_metadata_only(gw):
    wait_for_apps(gw, {"temp_sensor"})
    body = sample(gw, "/apps/temp_sensor/data/no/such/topic")
    assert body["data"] == {} and body["x-medkit"]["status"] == "metadata_only"


def test_bytes_base64(gw):
    wait_for_apps(gw, {"temp_sensor"})
    r = gw.get("/apps/temp_sensor/data/powertrain/engine/temperature", params={"bytes": "base64"})
    assert r.status_code == 200
    assert gw.get("/apps/temp_sensor/data/x", params={"bytes": "hex"}).status_code == 400


# ------------------------------------------------------------------ publish


def test_publish_reaches_a_subscriber(gw, robot):
    wait_for_apps(gw, {"controller"})
    url = "/apps/controller/data/body/lights/cmd"
    body = {"type": "std_msgs/msg/Bool", "data": {"data": True}}
    assert gw.put(url, json=body).status_code == 401
    assert gw.put(url, json=body, headers={"Authorization": "Bearer wrong"}).status_code == 401  # medkit: invalid_token
    auth = {"Authorization": f"Bearer {TOKEN}"}

    def delivered():
        r = gw.put(url, json=body, headers=auth)
        assert r.status_code == 200, r.text
        assert r.json()["x-medkit"]["status"] == "published"
        return any(m["topic"] == "/body/lights/cmd" and m["data"] == {"data": True}
                   for m in robot["controller"].echoed())

    poll_until(delivered, 30, interval=0.5, message="the controller to receive the published message")
    r = gw.put(url, json={"type": "nope_msgs/msg/Missing", "data": {}}, headers=auth)
    assert r.status_code == 400
    r = gw.put(url, json={"type": "std_msgs/msg/Bool", "data": {"no_such_field": 1}}, headers=auth)
    assert r.status_code == 400


def same_floats(got: list, want: list) -> bool:
    """Element-wise equality where NaN equals NaN (and nothing else)."""
    return len(got) == len(want) and all(
        (math.isnan(g) and math.isnan(w)) if math.isnan(w) else g == w for g, w in zip(got, want, strict=True))


def test_a_put_checks_the_entity_before_the_body(gw):
    """medkit's order: authentication, the entity (a wrong route is named), then the body."""
    wait_for_apps(gw, {"controller"})
    auth = {"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"}
    r = gw.put("/components/controller/data/body/lights/cmd", data=b"not json", headers=auth)
    assert r.status_code == 400, r.text
    assert r.json() == {"error_code": "invalid-parameter",
                        "message": "Invalid entity type for route: expected Component, got App",
                        "parameters": {"entity_id": "controller", "expected_type": "Component",
                                       "actual_type": "App"}}
    r = gw.put("/apps/no_such_app/data/body/lights/cmd", data=b"[1]", headers=auth)
    assert r.status_code == 404 and r.json()["error_code"] == "entity-not-found", r.text
    r = gw.put("/components/controller/data/body/lights/cmd", data=b"not json",
               headers={"Content-Type": "application/json"})
    assert r.status_code == 401, r.text   # authentication still comes first
    r = gw.put("/apps/controller/data/body/lights/cmd", data=b"not json", headers=auth)
    assert r.status_code == 400 and r.json()["error_code"] == "invalid-request", r.text


def test_nan_and_infinities_survive_get_and_put(gw):
    """REP 117: NaN invalid, +inf no return, -inf too close.  GET -> PUT is exact."""
    nan, inf = float("nan"), float("inf")
    sensor = publisher("scanner", "scan", "sensor_msgs/msg/LaserScan",
                       {"header": {"frame_id": "laser"}, "ranges": [1.5, nan, inf, -inf],
                        "range_min": 0.25, "range_max": inf, "intensities": [-inf, 3.0]},
                       namespace="/lidar")
    sink = RosNode({"node": "scan_sink", "namespace": "/lidar",
                    "subscribe": [{"topic": "replay", "type": "sensor_msgs/msg/LaserScan", "echo": True}]})
    try:
        wait_for_apps(gw, {"scanner", "scan_sink"})
        body = wait_for_data(gw, "/apps/scanner/data/lidar/scan")
        data = body["data"]
        assert data["ranges"] == [1.5, "NaN", "Infinity", "-Infinity"], data
        assert data["range_max"] == "Infinity" and data["range_min"] == 0.25, data
        assert data["intensities"] == ["-Infinity", 3.0], data
        # The sample passes the schema the gateway itself gives for its type, its floats read as the
        # README says (a number, or one of the strings the anyOf lists).
        items = {i["id"]: i for i in gw.get("/apps/scanner/data").json()["items"]}
        floats.validate(data, items["/lidar/scan"]["x-medkit"]["type_info"]["schema"])

        url = "/apps/scan_sink/data/lidar/replay"
        put = {"type": "sensor_msgs/msg/LaserScan", "data": data}
        auth = {"Authorization": f"Bearer {TOKEN}"}

        def replayed():
            r = gw.put(url, json=put, headers=auth)
            assert r.status_code == 200, r.text
            assert r.json()["data"] == data
            return [m["data"] for m in sink.echoed() if m["topic"] == "/lidar/replay"]

        got = poll_until(replayed, 30, interval=0.5, message="the sink to receive the replayed scan")[0]
        assert same_floats(got["ranges"], [1.5, nan, inf, -inf]), got
        assert got["range_max"] == inf and got["range_min"] == 0.25, got
        assert same_floats(got["intensities"], [-inf, 3.0]), got
        assert got["header"]["frame_id"] == "laser"
        # null still means NaN (medkit's clients write NaN that way); other spellings are refused.
        r = gw.put(url, json={"type": "sensor_msgs/msg/LaserScan", "data": {"range_max": None}},
                   headers=auth)
        assert r.status_code == 200, r.text
        r = gw.put(url, json={"type": "sensor_msgs/msg/LaserScan", "data": {"ranges": [1.0, "inf"]}},
                   headers=auth)
        assert r.status_code == 400 and r.json()["error_code"] == "invalid-request", r.text
        assert "data.ranges[1]" in r.json()["message"] and '"Infinity"' in r.json()["message"]
    finally:
        sensor.stop()
        sink.stop()


def test_publish_disabled_by_default(robot):
    gateway = Gateway()
    try:
        r = gateway.put("/apps/controller/data/body/lights/cmd",
                        json={"type": "std_msgs/msg/Bool", "data": {"data": True}})
        assert r.status_code == 403 and r.json()["error_code"] == "forbidden"
        assert gateway.get("/").json()["capabilities"]["publishing"] is False
    finally:
        gateway.stop()


# ------------------------------------------------------------------ the graph changes


def test_node_that_appears_and_leaves(gw):
    wait_for_apps(gw, {"temp_sensor"})
    extra = publisher("wiper", "state", "std_msgs/msg/Bool", {"data": False}, namespace="/body/wipers")
    try:
        wait_for_apps(gw, {"wiper"})
    finally:
        extra.stop()
    settled(lambda: "wiper" not in app_ids(gw), 30, message="wiper to leave")


# ------------------------------------------------------------------ health and the ROS worker dying


def _rosworker_pid(gateway) -> int:
    procs = psutil.Process(gateway.pid).children(recursive=True)
    workers = [p for p in procs if any("rosworker" in part for part in p.cmdline())]
    assert len(workers) == 1, [p.cmdline() for p in procs]
    return workers[0].pid


def test_rosworker_crash_is_503_then_recovers(robot):
    gateway = Gateway("--sample-timeout", "2")
    try:
        wait_for_apps(gateway, {"pressure_sensor"})
        path = "/functions/chassis/data/chassis/brakes/pressure"
        wait_for_data(gateway, path)
        health = gateway.get("/health").json()
        assert health["status"] == "healthy"
        assert health["x-medkit-subscription-executor"]["worker_alive"] is True

        os.kill(_rosworker_pid(gateway), signal.SIGKILL)
        seen = set()

        def down_seen():
            h = gateway.get("/health", timeout=5)
            assert h.status_code == 200
            if not h.json()["x-medkit-subscription-executor"]["worker_alive"]:
                seen.add("health")
            r = gateway.get(path, timeout=10)
            # 504: a request that went out just as the worker died, answered by nobody.
            assert r.status_code in (200, 503, 504), r.text
            if r.status_code == 504:
                assert r.json()["error_code"] == "not-responding"
            if r.status_code == 503:
                assert r.headers["Retry-After"]
                assert r.json()["vendor_code"] in ("x-medkit-ros-worker-unavailable",
                                                   "x-medkit-gateway-shutdown")
                seen.add("503")
            return seen

        poll_until(down_seen, 20, interval=0.02, message="the HTTP side to notice the ROS worker is down")
        # ... and the supervisor restarts it: data flows again.
        poll_until(lambda: gateway.get("/health").json()["x-medkit-subscription-executor"]["worker_alive"],
                   60, message="the ROS worker to come back")
        wait_for_data(gateway, path, timeout=60)
    finally:
        gateway.stop()
