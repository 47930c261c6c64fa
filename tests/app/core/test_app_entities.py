"""app/core/entities.py: the ROS graph → SOVD entities, as pure functions."""

from __future__ import annotations

import pytest

from app.core import entities
from app.core.entities import HostInfo, build, data_items, host_component_id
from tests.support.fakeworker import node, topics_of

HOST = HostInfo("My-Robot.local", "Debian GNU/Linux 12 (bookworm)", "x86_64")
TEMP = ("/powertrain/engine/temperature", "sensor_msgs/msg/Temperature")
PRESSURE = ("/chassis/brakes/pressure", "std_msgs/msg/Float32")
CMD = ("/body/lights/cmd", "std_msgs/msg/Bool")


def graph(*nodes, generation=3):
    return {"generation": generation, "unchanged": False, "nodes": list(nodes), "topics": topics_of(list(nodes))}


@pytest.mark.parametrize("hostname, expected", [
    ("vm", "vm"),
    ("My-Robot.local", "my-robot_local"),
    ("robot one", "robot_one"),
    ("Röbot#7!", "rbot7"),
    ("", "unknown_host"),
    ("#!%", "unknown_host"),
    ("a" * 300, "a" * 256),
])
def test_host_component_id(hostname, expected):
    assert host_component_id(hostname) == expected


def test_os_pretty_name_reads_os_release(tmp_path):
    f = tmp_path / "os-release"
    f.write_text('NAME="Debian"\nPRETTY_NAME="Debian GNU/Linux 12 (bookworm)"\n')
    assert entities.os_pretty_name([str(tmp_path / "missing"), str(f)]) == "Debian GNU/Linux 12 (bookworm)"


def test_host_component():
    idx = build(graph(), HOST)
    assert list(idx.collections["components"]) == ["my-robot_local"]
    comp = idx.get("components", "my-robot_local")
    item = comp.listing_item()
    assert item == {"id": "my-robot_local", "name": "My-Robot.local",
                    "href": "/api/v1/components/my-robot_local", "type": "component",
                    "description": "Debian GNU/Linux 12 (bookworm) on x86_64",
                    "x-medkit": {"source": "runtime"}}
    assert idx.collections["areas"] == {}


def test_apps_one_per_node_hidden_nodes_left_out():
    idx = build(graph(node("/powertrain/engine/temp_sensor", [TEMP]),
                      node("/_hidden_helper"), node("/chassis/_daemon"),
                      node("/chassis/brakes/pressure_sensor", [PRESSURE])), HOST)
    assert sorted(idx.collections["apps"]) == ["pressure_sensor", "temp_sensor"]
    app = idx.get("apps", "temp_sensor")
    assert app.listing_item() == {
        "id": "temp_sensor", "name": "temp_sensor", "href": "/api/v1/apps/temp_sensor", "type": "app",
        "x-medkit": {"source": "heuristic", "is_online": True, "component_id": "my-robot_local",
                     "ros2": {"node": "/powertrain/engine/temp_sensor"}},
    }


def test_app_detail():
    app = build(graph(node("/powertrain/engine/temp_sensor", [TEMP])), HOST).get("apps", "temp_sensor")
    d = app.detail()
    assert d["id"] == "temp_sensor" and d["type"] == "app" and d["name"] == "temp_sensor"
    assert d["data"] == "/api/v1/apps/temp_sensor/data"
    assert d["is-located-on"] == "/api/v1/components/my-robot_local"
    assert d["belongs-to"] == "/api/v1/apps/temp_sensor/belongs-to"
    assert "depends-on" not in d  # medkit links it only when there are dependencies
    for name in ("operations", "configurations", "faults", "logs", "triggers"):
        assert d[name] == f"/api/v1/apps/temp_sensor/{name}"
    assert d["status"] == "/api/v1/apps/temp_sensor/status"
    assert d["capabilities"] == [
        {"name": "status", "href": "/api/v1/apps/temp_sensor/status"},
        {"name": "data", "href": "/api/v1/apps/temp_sensor/data"},
        {"name": "operations", "href": "/api/v1/apps/temp_sensor/operations"},
        {"name": "configurations", "href": "/api/v1/apps/temp_sensor/configurations"},
        {"name": "faults", "href": "/api/v1/apps/temp_sensor/faults"},
        {"name": "logs", "href": "/api/v1/apps/temp_sensor/logs"},
        {"name": "triggers", "href": "/api/v1/apps/temp_sensor/triggers"},
        {"name": "is-located-on", "href": "/api/v1/apps/temp_sensor/is-located-on"},
        {"name": "belongs-to", "href": "/api/v1/apps/temp_sensor/belongs-to"}]
    assert d["_links"] == {"self": "/api/v1/apps/temp_sensor", "collection": "/api/v1/apps",
                           "is-located-on": "/api/v1/components/my-robot_local",
                           "belongs-to": "/api/v1/apps/temp_sensor/belongs-to"}
    assert d["x-medkit"] == app.listing_item()["x-medkit"]


def test_component_function_and_area_details():
    idx = build(graph(node("/powertrain/engine/temp_sensor", [TEMP]), node("/powertrain/gearbox")), HOST)
    c = idx.get("components", "my-robot_local").detail()
    base = "/api/v1/components/my-robot_local"
    assert (c["data"], c["subcomponents"], c["hosts"]) == (base + "/data", base + "/subcomponents",
                                                           base + "/hosts")
    assert "depends-on" not in c and "belongs-to" not in c
    for name in ("operations", "configurations", "faults", "logs", "triggers"):
        assert c[name] == f"{base}/{name}"
    assert c["status"] == base + "/status"
    caps = [{"name": n, "href": f"{base}/{n}"} for n in ("status", "data", "operations", "configurations", "faults",
                                                         "logs", "subcomponents", "hosts", "triggers")]
    assert c["capabilities"] == caps and c["x-medkit"] == {"source": "runtime", "capabilities": caps}
    assert c["_links"] == {"self": base, "collection": "/api/v1/components"}
    f = idx.get("functions", "powertrain").detail()
    assert f["hosts"] == "/api/v1/functions/powertrain/hosts"
    assert f["x-medkit"] == {"source": "runtime", "hosts": ["gearbox", "temp_sensor"]}
    for name in ("operations", "configurations", "faults", "logs", "triggers"):
        assert f[name] == f"/api/v1/functions/powertrain/{name}"
    assert [cap["name"] for cap in f["capabilities"]] == ["hosts", "data", "operations", "configurations", "faults",
                                                          "logs", "triggers"]
    # No areas exist in runtime discovery; one built by hand gets medkit's area URIs.
    a = entities.Entity("areas", "engine", "Engine", {}).detail()
    assert (a["subareas"], a["components"], a["contains"]) == (
        "/api/v1/areas/engine/subareas", "/api/v1/areas/engine/components", "/api/v1/areas/engine/contains")
    assert [cap["name"] for cap in a["capabilities"]] == ["subareas", "contains", "data"]


def test_relations():
    idx = build(graph(node("/powertrain/engine/temp_sensor", [TEMP]), node("/chassis/brakes/p", [PRESSURE])),
                HOST)
    comp, app = idx.get("components", "my-robot_local"), idx.get("apps", "temp_sensor")
    func = idx.get("functions", "chassis")
    assert [e.id for e in idx.related(comp, "hosts")] == ["p", "temp_sensor"]
    assert [e.id for e in idx.related(func, "hosts")] == ["p"]
    assert [e.id for e in idx.related(app, "is-located-on")] == ["my-robot_local"]
    for owner, relation in ((comp, "subcomponents"), (comp, "depends-on"), (app, "belongs-to"),
                            (app, "depends-on")):
        assert idx.related(owner, relation) == []
    body = idx.relation_body(app, "is-located-on")
    assert body == {"items": [comp.listing_item()], "x-medkit": {"total_count": 1},
                    "_links": {"self": "/api/v1/apps/temp_sensor/is-located-on",
                               "app": "/api/v1/apps/temp_sensor"}}
    assert idx.relation_body(comp, "subcomponents")["_links"] == {
        "self": "/api/v1/components/my-robot_local/subcomponents",
        "parent": "/api/v1/components/my-robot_local"}


def test_same_node_name_in_several_namespaces_gets_namespace_ids():
    idx = build(graph(node("/a/b/n"), node("/c/n"), node("/n"), node("/c/other")), HOST)
    assert sorted(idx.collections["apps"]) == ["a_b_n", "c_n", "n", "other"]
    assert idx.get("apps", "a_b_n").x_medkit["ros2"]["node"] == "/a/b/n"
    assert idx.get("apps", "a_b_n").name == "n"


def test_derived_id_never_takes_a_plain_node_name():
    idx = build(graph(node("/x/n"), node("/y/n"), node("/x_n")), HOST)
    assert sorted(idx.collections["apps"]) == ["x_n", "x_n_2", "y_n"]
    assert idx.get("apps", "x_n").x_medkit["ros2"]["node"] == "/x_n"
    assert idx.get("apps", "x_n_2").x_medkit["ros2"]["node"] == "/x/n"


def test_two_nodes_with_one_fqn_make_one_app():
    idx = build(graph(node("/dup", [TEMP]), node("/dup", [PRESSURE])), HOST)
    assert list(idx.collections["apps"]) == ["dup"]
    assert {TEMP[0], PRESSURE[0]} <= set(idx.get("apps", "dup").topics)


def test_functions_by_first_namespace_segment():
    idx = build(graph(node("/powertrain/engine/temp_sensor", [TEMP]), node("/powertrain/gearbox"),
                      node("/chassis/brakes/pressure_sensor", [PRESSURE]), node("/teleop")), HOST)
    assert sorted(idx.collections["functions"]) == ["chassis", "powertrain", "root"]
    power = idx.get("functions", "powertrain")
    assert power.name == "powertrain"
    assert power.hosts == ["gearbox", "temp_sensor"]
    item = power.listing_item()
    assert item["type"] == "function" and item["hosts"] == ["gearbox", "temp_sensor"]
    assert item["x-medkit"] == {"source": "runtime"}
    assert idx.get("functions", "root").hosts == ["teleop"]


def test_elsewhere_finds_other_types():
    idx = build(graph(node("/powertrain/engine/temp_sensor")), HOST)
    assert idx.elsewhere("components", "temp_sensor").type_name == "App"
    assert idx.elsewhere("apps", "powertrain").type_name == "Function"
    assert idx.elsewhere("apps", "my-robot_local").type_name == "Component"
    assert idx.elsewhere("apps", "nothing") is None


def test_app_data_items_with_directions_and_type_info():
    n = node("/body/lights/controller", [("/body/lights/state", "std_msgs/msg/Bool")], [CMD])
    n["publishes"].append(["/body/lights/echo", "std_msgs/msg/String"])
    n["subscribes"].append(["/body/lights/echo", "std_msgs/msg/String"])
    app = build(graph(n), HOST).get("apps", "controller")
    infos = {"std_msgs/msg/Bool": {"schema": {"type": "object"}, "default_value": {"data": False}},
             "std_msgs/msg/String": None}
    body = data_items(app, infos)
    by_id = {i["id"]: i for i in body["items"]}
    assert set(by_id) == {"/body/lights/state", "/body/lights/cmd", "/body/lights/echo", "/rosout",
                          "/parameter_events"}
    assert by_id["/body/lights/cmd"] == {
        "id": "/body/lights/cmd", "name": "/body/lights/cmd", "category": "currentData",
        "x-medkit": {"ros2": {"topic": "/body/lights/cmd", "type": "std_msgs/msg/Bool", "direction": "subscribe"},
                     "type_info": {"schema": {"type": "object"}, "default_value": {"data": False}}}}
    assert by_id["/body/lights/state"]["x-medkit"]["ros2"]["direction"] == "publish"
    assert by_id["/body/lights/echo"]["x-medkit"]["ros2"]["direction"] == "both"
    assert "type_info" not in by_id["/body/lights/echo"]["x-medkit"]  # not installed
    assert "type_info" not in by_id["/rosout"]["x-medkit"]            # not asked
    assert body["x-medkit"] == {"entity_id": "controller", "total_count": 5}


def test_component_and_function_data_are_unions_with_members():
    talker = node("/demo/talker", [("/chatter", "std_msgs/msg/String")])
    listener = node("/demo/listener", [], [("/chatter", "std_msgs/msg/String")])
    brakes = node("/chassis/brakes/pressure_sensor", [PRESSURE])
    idx = build(graph(talker, listener, brakes), HOST)

    body = data_items(idx.get("functions", "demo"), {})
    by_id = {i["id"]: i for i in body["items"]}
    assert set(by_id) == {"/chatter", "/rosout", "/parameter_events"}
    assert by_id["/chatter"]["x-medkit"]["ros2"]["direction"] == "both"
    assert by_id["/chatter"]["x-medkit"]["member_ids"] == ["listener", "talker"]
    assert by_id["/rosout"]["x-medkit"]["ros2"]["direction"] == "publish"
    assert body["x-medkit"] == {"entity_id": "demo", "total_count": 3, "aggregated": True,
                                "aggregation_sources": ["listener", "talker"], "aggregation_level": "function"}

    comp = data_items(idx.get("components", "my-robot_local"), {})
    ids = [i["id"] for i in comp["items"]]
    assert ids == sorted(ids) and len(ids) == len(set(ids))       # one item per topic
    assert set(ids) == {"/chatter", "/rosout", "/parameter_events", "/chassis/brakes/pressure"}
    assert comp["x-medkit"]["aggregation_level"] == "component"
    assert comp["x-medkit"]["aggregation_sources"] == ["listener", "pressure_sensor", "talker"]
    rosout = next(i for i in comp["items"] if i["id"] == "/rosout")
    assert rosout["x-medkit"]["member_ids"] == ["listener", "pressure_sensor", "talker"]


def test_malformed_graph_entries_are_ignored():
    g = {"generation": 2, "nodes": [None, {"name": 3}, node("/ok")], "topics": [None, {"x": 1}]}
    idx = build(g, HOST)
    assert list(idx.collections["apps"]) == ["ok"]
    assert idx.generation == 2
