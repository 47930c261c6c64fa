"""app/core/discovery.py (and the graph cache of app/core/rosclient.py) against a fake ROS worker."""

from __future__ import annotations

import platform
from urllib.parse import unquote

import pytest

from tests.support.fakeworker import ROBOT, error_of, make_app, node


def test_areas_are_empty(client):
    r = client.get("/api/v1/areas")
    assert r.status_code == 200
    assert r.headers["Content-Type"] == "application/json"
    assert r.get_json() == {"items": [], "x-medkit": {"total_count": 0}}


def test_components_is_the_host(client):
    body = client.get("/api/v1/components").get_json()
    assert body["x-medkit"] == {"total_count": 1}
    (host,) = body["items"]
    assert host["id"] == "test-robot" and host["name"] == "test-robot"
    assert host["href"] == "/api/v1/components/test-robot" and host["type"] == "component"
    assert host["description"].endswith(" on " + platform.machine())
    assert host["x-medkit"] == {"source": "runtime"}


def test_apps_listing(client):
    body = client.get("/api/v1/apps").get_json()
    assert [i["id"] for i in body["items"]] == ["controller", "pressure_sensor", "temp_sensor"]
    assert body["x-medkit"] == {"total_count": 3}
    temp = body["items"][2]
    assert temp == {"id": "temp_sensor", "name": "temp_sensor", "href": "/api/v1/apps/temp_sensor",
                    "type": "app", "x-medkit": {"source": "heuristic", "is_online": True,
                                                "component_id": "test-robot",
                                                "ros2": {"node": "/powertrain/engine/temp_sensor"}}}


def test_functions_listing(client):
    body = client.get("/api/v1/functions").get_json()
    assert [(i["id"], i["name"], i["hosts"]) for i in body["items"]] == [
        ("body", "body", ["controller"]), ("chassis", "chassis", ["pressure_sensor"]),
        ("powertrain", "powertrain", ["temp_sensor"])]
    assert body["items"][0]["href"] == "/api/v1/functions/body"
    assert body["items"][0]["x-medkit"]["source"] == "runtime"


def test_app_detail(client):
    r = client.get("/api/v1/apps/temp_sensor")
    assert r.status_code == 200
    d = r.get_json()
    assert d["id"] == "temp_sensor" and d["type"] == "app"
    assert d["data"] == "/api/v1/apps/temp_sensor/data"
    assert d["is-located-on"] == "/api/v1/components/test-robot"
    assert d["belongs-to"] == "/api/v1/apps/temp_sensor/belongs-to"
    assert d["operations"] == "/api/v1/apps/temp_sensor/operations"
    assert d["configurations"] == "/api/v1/apps/temp_sensor/configurations"
    assert d["faults"] == "/api/v1/apps/temp_sensor/faults"
    assert d["logs"] == "/api/v1/apps/temp_sensor/logs"
    assert d["triggers"] == "/api/v1/apps/temp_sensor/triggers"
    assert d["status"] == "/api/v1/apps/temp_sensor/status"  # medkit's, first
    assert [c["name"] for c in d["capabilities"]] == ["status", "data", "operations", "configurations", "faults",
                                                      "logs", "triggers", "is-located-on", "belongs-to"]
    assert {"name": "is-located-on", "href": "/api/v1/apps/temp_sensor/is-located-on"} in d["capabilities"]
    assert d["_links"] == {"self": "/api/v1/apps/temp_sensor", "collection": "/api/v1/apps",
                           "is-located-on": "/api/v1/components/test-robot",
                           "belongs-to": "/api/v1/apps/temp_sensor/belongs-to"}
    assert d["x-medkit"]["ros2"] == {"node": "/powertrain/engine/temp_sensor"}


def test_component_and_function_details(client):
    c = client.get("/api/v1/components/test-robot").get_json()
    assert c["id"] == "test-robot" and c["type"] == "component" and c["data"].endswith("/data")
    assert c["_links"] == {"self": "/api/v1/components/test-robot", "collection": "/api/v1/components"}
    assert c["hosts"] == "/api/v1/components/test-robot/hosts"
    assert c["subcomponents"] == "/api/v1/components/test-robot/subcomponents"
    assert c["operations"] == "/api/v1/components/test-robot/operations"
    assert c["triggers"] == "/api/v1/components/test-robot/triggers"
    assert c["status"] == "/api/v1/components/test-robot/status"
    assert [cap["name"] for cap in c["capabilities"]] == ["status", "data", "operations", "configurations",
                                                          "faults", "logs", "subcomponents", "hosts", "triggers"]
    assert c["x-medkit"]["capabilities"] == c["capabilities"]
    f = client.get("/api/v1/functions/powertrain").get_json()
    assert f["type"] == "function" and f["hosts"] == "/api/v1/functions/powertrain/hosts"
    assert f["x-medkit"]["hosts"] == ["temp_sensor"]
    assert f["_links"] == {"self": "/api/v1/functions/powertrain", "collection": "/api/v1/functions"}
    assert f["configurations"] == "/api/v1/functions/powertrain/configurations"
    assert [cap["name"] for cap in f["capabilities"]] == ["hosts", "data", "operations", "configurations", "faults",
                                                          "logs", "triggers"]


def test_is_located_on(client):
    r = client.get("/api/v1/apps/temp_sensor/is-located-on")
    assert r.status_code == 200
    body = r.get_json()
    (host,) = body["items"]
    assert host["id"] == "test-robot" and host["type"] == "component"
    assert host["name"] == "test-robot" and host["href"] == "/api/v1/components/test-robot"
    assert body["x-medkit"] == {"total_count": 1}
    assert body["_links"] == {"self": "/api/v1/apps/temp_sensor/is-located-on",
                              "app": "/api/v1/apps/temp_sensor"}


@pytest.mark.parametrize("path, ids, owner", [
    ("/api/v1/components/test-robot/hosts", ["controller", "pressure_sensor", "temp_sensor"],
     ("component", "/api/v1/components/test-robot")),
    ("/api/v1/components/test-robot/subcomponents", [], ("parent", "/api/v1/components/test-robot")),
    ("/api/v1/components/test-robot/depends-on", [], ("component", "/api/v1/components/test-robot")),
    ("/api/v1/apps/temp_sensor/is-located-on", ["test-robot"], ("app", "/api/v1/apps/temp_sensor")),
    ("/api/v1/apps/temp_sensor/belongs-to", [], ("app", "/api/v1/apps/temp_sensor")),
    ("/api/v1/apps/controller/depends-on", [], ("app", "/api/v1/apps/controller")),
    ("/api/v1/functions/powertrain/hosts", ["temp_sensor"], ("function", "/api/v1/functions/powertrain")),
    ("/api/v1/functions/body/hosts", ["controller"], ("function", "/api/v1/functions/body")),
])
def test_relation_collections(client, path, ids, owner):
    r = client.get(path)
    assert r.status_code == 200 and r.headers["Content-Type"] == "application/json"
    body = r.get_json()
    assert [i["id"] for i in body["items"]] == ids
    assert body["x-medkit"] == {"total_count": len(ids)}
    assert body["_links"] == {"self": path, owner[0]: owner[1]}
    for item in body["items"]:
        assert {"id", "name", "href", "type"} <= set(item)
        assert item["href"] == f"/api/v1/{item['type']}s/{item['id']}"


def test_every_detail_link_answers(client):
    """HATEOAS: every URI an entity detail advertises answers 200 (nothing a client follows is a 404).

    The fake worker knows no ``op_list``/``param_list``/``fault_list``: those three links are followed through the
    real gateway and ROS worker in tests/system/test_app_e2e.py (test_every_link_of_every_entity_answers).
    """
    for path in ("/api/v1/components/test-robot", "/api/v1/apps/temp_sensor", "/api/v1/functions/powertrain"):
        d = client.get(path).get_json()
        uris = {v for k, v in d.items() if isinstance(v, str) and v.startswith("/api/v1/")}
        uris |= {c["href"] for c in d["capabilities"]} | set(d["_links"].values())
        assert len(uris) >= 3
        uris = {u for u in uris if u.rsplit("/", 1)[1] not in ("operations", "configurations", "faults")}
        for uri in uris:
            assert client.get(uri).status_code == 200, uri


@pytest.mark.parametrize("path, message, param", [
    ("/api/v1/components/nope/hosts", "Component not found", "component_id"),
    ("/api/v1/components/nope/subcomponents", "Component not found", "component_id"),
    ("/api/v1/components/nope/depends-on", "Component not found", "component_id"),
    ("/api/v1/components/temp_sensor/hosts", "Component not found", "component_id"),  # an app's id
    ("/api/v1/functions/nope/hosts", "Function not found", "function_id"),
    ("/api/v1/functions/temp_sensor/hosts", "Function not found", "function_id"),
    ("/api/v1/areas/nope/components", "Area not found", "area_id"),
    ("/api/v1/areas/nope/contains", "Area not found", "area_id"),
    ("/api/v1/areas/nope/subareas", "Area not found", "area_id"),
    ("/api/v1/areas/powertrain/components", "Area not found", "area_id"),  # a function's id
])
def test_relation_of_unknown_owner_is_medkits_typed_404(client, path, message, param):
    r = client.get(path)
    assert r.status_code == 404
    entity_id = path.split("/")[4]
    assert r.get_json() == {"error_code": "entity-not-found", "message": message,
                            "parameters": {param: entity_id}}


@pytest.mark.parametrize("path, message, param", [
    ("/api/v1/components/a.b/hosts", "Invalid component ID", "component_id"),
    ("/api/v1/components/a.b/depends-on", "Invalid component ID", "component_id"),
    ("/api/v1/functions/a.b/hosts", "Invalid function ID", "function_id"),
    ("/api/v1/areas/a.b/components", "Invalid area ID", "area_id"),
    ("/api/v1/areas/a.b/contains", "Invalid area ID", "area_id"),
    ("/api/v1/areas/a.b/subareas", "Invalid area ID", "area_id"),
])
def test_relation_with_invalid_owner_id_is_medkits_typed_400(client, fw, path, message, param):
    before = len(fw.requests)
    r = client.get(path)
    assert r.status_code == 400
    assert r.get_json() == {"error_code": "invalid-parameter", "message": message, "parameters": {
        "details": "Entity ID contains invalid character: '.'. Only alphanumeric, underscore and hyphen "
                   "are allowed", param: "a.b"}}
    assert len(fw.requests) == before  # nothing asked of the ROS worker


ONLY = ". Only alphanumeric, underscore and hyphen are allowed"


@pytest.mark.parametrize("bad, detail", [
    ("a.b", "Entity ID contains invalid character: '.'" + ONLY),
    ("a%20b", "Entity ID contains invalid character: ' '" + ONLY),
    ("a%7Fb", "Entity ID contains invalid character: '0x7f'" + ONLY),
    ("x" * 257, "Entity ID too long (max 256 characters)"),
    ("%C3%A9t%C3%A9", "Entity ID contains invalid character: '0xc3'" + ONLY),  # medkit names the byte
])
@pytest.mark.parametrize("collection", ["areas", "components", "apps", "functions"])
def test_invalid_entity_id(client, fw, collection, bad, detail):
    before = len(fw.requests)
    r = client.get(f"/api/v1/{collection}/{bad}")
    assert r.status_code == 400
    body = r.get_json()
    assert body["error_code"] == "invalid-parameter" and body["message"] == "Invalid entity ID"
    assert body["parameters"] == {"details": detail, "entity_id": unquote(bad)}
    assert len(fw.requests) == before  # nothing asked of the ROS worker


def test_longest_valid_id_is_a_404(client):
    r = client.get("/api/v1/apps/" + "x" * 256)
    assert r.status_code == 404


@pytest.mark.parametrize("path", ["/api/v1/apps/nope", "/api/v1/components/nope", "/api/v1/functions/nope",
                                  "/api/v1/areas/nope", "/api/v1/apps/nope/is-located-on",
                                  "/api/v1/apps/nope/belongs-to", "/api/v1/apps/nope/depends-on",
                                  "/api/v1/apps/nope/data", "/api/v1/components/nope/data/x/y"])
def test_unknown_entity(client, path):
    r = client.get(path)
    assert r.status_code == 404
    assert r.get_json() == {"error_code": "entity-not-found", "message": "Entity not found",
                            "parameters": {"entity_id": "nope"}}


@pytest.mark.parametrize("path, expected, actual", [
    ("/api/v1/components/temp_sensor", "Component", "App"),
    ("/api/v1/apps/test-robot", "App", "Component"),
    ("/api/v1/apps/powertrain", "App", "Function"),
    ("/api/v1/functions/temp_sensor", "Function", "App"),
    ("/api/v1/areas/powertrain", "Area", "Function"),
    ("/api/v1/components/temp_sensor/data", "Component", "App"),
    ("/api/v1/functions/temp_sensor/data/powertrain/engine/temperature", "Function", "App"),
    ("/api/v1/apps/test-robot/is-located-on", "App", "Component"),
    ("/api/v1/apps/powertrain/belongs-to", "App", "Function"),
    ("/api/v1/apps/test-robot/depends-on", "App", "Component"),
])
def test_id_of_another_type(client, path, expected, actual):
    r = client.get(path)
    assert r.status_code == 400
    assert r.get_json() == {
        "error_code": "invalid-parameter",
        "message": f"Invalid entity type for route: expected {expected}, got {actual}",
        "parameters": {"entity_id": path.split("/")[4], "expected_type": expected, "actual_type": actual}}


def test_is_located_on_only_for_apps(client):
    r = client.get("/api/v1/components/test-robot/is-located-on")
    assert r.status_code == 404 and r.get_json()["error_code"] == "resource-not-found"


def test_node_names_in_several_namespaces(client, fw):
    fw.set_graph([node("/left/wheel/driver"), node("/right/wheel/driver"), node("/imu")])
    ids = [i["id"] for i in client.get("/api/v1/apps").get_json()["items"]]
    assert ids == ["imu", "left_wheel_driver", "right_wheel_driver"]
    d = client.get("/api/v1/apps/left_wheel_driver").get_json()
    assert d["name"] == "driver" and d["x-medkit"]["ros2"]["node"] == "/left/wheel/driver"


def test_hidden_nodes_are_not_apps(client, fw):
    fw.set_graph([node("/_ros2cli_daemon"), node("/tools/_helper"), node("/visible")])
    ids = [i["id"] for i in client.get("/api/v1/apps").get_json()["items"]]
    assert ids == ["visible"]
    assert client.get("/api/v1/apps/_helper").status_code == 404


def test_graph_changes_show_up_and_generation_is_used(client, fw):
    assert len(client.get("/api/v1/apps").get_json()["items"]) == 3
    assert len(client.get("/api/v1/apps").get_json()["items"]) == 3
    graph_calls = fw.calls("graph")
    # The second ask carries the generation the cache holds.
    assert graph_calls[-1] == {"since": fw.generation}
    fw.set_graph(list(ROBOT) + [node("/powertrain/gearbox/controller2")])
    ids = [i["id"] for i in client.get("/api/v1/apps").get_json()["items"]]
    assert "controller2" in ids
    fw.set_graph(list(ROBOT[:1]))
    ids = [i["id"] for i in client.get("/api/v1/apps").get_json()["items"]]
    assert ids == ["temp_sensor"]
    assert client.get("/api/v1/apps/controller2").status_code == 404


def test_graph_is_asked_at_most_once_per_refresh_interval(fw):
    client = make_app(fw, SOVD_GRAPH_REFRESH_S=60.0).test_client()
    for _ in range(20):
        assert client.get("/api/v1/apps").status_code == 200
        assert client.get("/api/v1/apps/temp_sensor").status_code == 200
    assert len(fw.calls("graph")) == 1


def test_no_ros_worker_gives_503_with_retry_after(tmp_path):
    client = make_app(runtime_dir=str(tmp_path)).test_client()
    r = client.get("/api/v1/apps")
    error_of(r, 503, "vendor-error", "x-medkit-ros-worker-unavailable")
    assert r.headers["Retry-After"] == "2"


def test_silent_worker_on_graph_gives_504(fw):
    fw.silent.add("graph")
    client = make_app(fw, ipc_timeout=0.3).test_client()
    r = client.get("/api/v1/components")
    assert r.status_code == 504
    assert r.get_json()["error_code"] == "not-responding"


def test_busy_worker_serves_the_cached_graph(fw):
    client = make_app(fw, ipc_timeout=0.3).test_client()
    assert client.get("/api/v1/apps").status_code == 200
    fw.silent.add("graph")
    r = client.get("/api/v1/apps")
    assert r.status_code == 200 and len(r.get_json()["items"]) == 3


def test_malformed_graph_answer_is_a_500_without_details(fw):
    fw.nodes = "not a list"  # the worker answers nonsense
    client = make_app(fw).test_client()
    r = client.get("/api/v1/apps")
    assert r.status_code == 500
    body = r.get_json()
    assert body["error_code"] == "internal-error"
    assert "Traceback" not in r.get_data(as_text=True)


def test_concurrent_requests_never_get_a_graph_older_than_a_refresh(fw):
    """A worker that was not asked for a while does not serve its old graph to the requests that
    arrive while one of them refreshes it (the dashboard asks for components and functions at
    once, and got the functions of the graph at boot)."""
    import threading
    import time

    app = make_app(fw, SOVD_GRAPH_REFRESH_S=0.05)
    assert len(app.test_client().get("/api/v1/apps").get_json()["items"]) == 3
    time.sleep(0.2)   # the cache is now older than two refresh intervals
    fw.set_graph(list(ROBOT) + [node("/powertrain/gearbox/controller2")])
    fw.delays["graph"] = 0.5   # the first request's refresh is in flight while the others arrive
    start = threading.Barrier(4)
    seen: list[list[str]] = []

    def ask():
        client = app.test_client()
        start.wait(10)
        seen.append([i["id"] for i in client.get("/api/v1/functions/powertrain/hosts").get_json()["items"]])

    threads = [threading.Thread(target=ask) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert len(seen) == 4
    assert all("controller2" in ids for ids in seen), seen


def test_a_not_found_is_confirmed_on_a_fresh_graph(fw):
    """Each HTTP worker caches the graph on its own: an entity that one worker already shows must
    not be a 404 from another whose cache is a moment older (a POST after a GET saw this)."""
    client = make_app(fw, SOVD_GRAPH_REFRESH_S=60.0).test_client()
    assert client.get("/api/v1/apps/temp_sensor").status_code == 200
    fw.set_graph(list(ROBOT) + [node("/powertrain/gearbox/controller2")])
    asked = len(fw.calls("graph"))
    assert client.get("/api/v1/apps/controller2").status_code == 200
    assert client.get("/api/v1/functions/powertrain/hosts").status_code == 200
    assert len(fw.calls("graph")) == asked + 1      # one ask confirmed the miss; the hit needs none
    r = client.get("/api/v1/apps/no_such_app")
    assert r.status_code == 404 and r.get_json()["parameters"] == {"entity_id": "no_such_app"}
    assert len(fw.calls("graph")) == asked + 2      # a real miss costs one ask (unchanged: cheap)
