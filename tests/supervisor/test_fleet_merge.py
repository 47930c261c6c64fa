"""The fleet's merged tree (supervisor/fleet/merge.py): medkit's EntityMerger rules over the robots' trees."""

from __future__ import annotations

import orjson

from supervisor.fleet.merge import RobotTree, merge, tree_problem


def item(collection: str, entity_id: str, **extra) -> dict:
    return {"id": entity_id, "name": entity_id, "href": f"/api/v1/{collection}/{entity_id}",
            "type": collection[:-1], "x-medkit": {"source": "heuristic", **extra.pop("ext", {})}, **extra}


def robot(name: str, order: int, host: str, apps: list[str], functions: dict[str, list[str]],
          available: bool = True, areas: tuple[str, ...] = ()) -> RobotTree:
    return RobotTree(name, order, available, {
        "areas": [item("areas", a) for a in areas],
        "components": [item("components", host, description=f"{host} machine")],
        "apps": [item("apps", a, ext={"component_id": host, "is_online": True}) for a in apps],
        "functions": [item("functions", f, hosts=hosts) for f, hosts in functions.items()],
    })


def test_the_robot_merged_first_keeps_an_app_id_the_others_are_renamed():
    tree = merge([robot("b", 2, "hb", ["ctl", "cam"], {}), robot("a", 1, "ha", ["ctl"], {}),
                  robot("c", 3, "hc", ["ctl"], {})], generation=7)
    apps = tree.items["apps"]
    assert sorted(apps) == ["b__ctl", "c__ctl", "cam", "ctl"]
    assert tree.routes[("apps", "ctl")] == ("a", "ctl") and tree.routes[("apps", "b__ctl")] == ("b", "ctl")
    assert apps["b__ctl"]["name"] == "b__ctl" and apps["b__ctl"]["href"] == "/api/v1/apps/b__ctl"
    assert apps["b__ctl"]["x-medkit"]["source"] == "peer:b" and apps["b__ctl"]["x-medkit"]["contributors"] == ["peer:b"]
    assert tree.routes[("apps", "cam")] == ("b", "cam")
    assert tree.member_id("b", "ctl") == "b__ctl" and tree.member_id("b", "cam") == "cam"
    assert tree.member_id("a", "ctl") == "ctl" and tree.generation == 7


def test_a_function_several_robots_offer_is_merged_with_remapped_hosts_and_served_here():
    tree = merge([robot("a", 1, "ha", ["ctl", "x"], {"body": ["ctl"], "solo": ["x"]}),
                  robot("b", 2, "hb", ["ctl"], {"body": ["ctl"]})], generation=1)
    body = tree.items["functions"]["body"]
    assert body["hosts"] == ["ctl", "b__ctl"]
    assert body["x-medkit"]["contributors"] == ["peer:a", "peer:b"]
    assert ("functions", "body") not in tree.routes                      # spans robots: served here
    assert tree.routes[("functions", "solo")] == ("a", "solo")           # one robot's: that robot's
    found = tree.entity("functions", "body")
    assert found["route"] is None and [h["id"] for h in found["hosts"]] == ["ctl", "b__ctl"]
    assert found["contributors"] == ["a", "b"]


def test_components_merge_by_id_route_to_the_last_robot_and_warn_on_a_collision():
    tree = merge([robot("a", 1, "shared", [], {}), robot("b", 2, "shared", [], {}), robot("c", 3, "own", [], {})], 1)
    assert sorted(tree.items["components"]) == ["own", "shared"]
    assert tree.routes[("components", "shared")] == ("b", "shared")     # last writer
    assert tree.items["components"]["shared"]["x-medkit"]["contributors"] == ["peer:a", "peer:b"]
    assert tree.warnings == [{
        "code": "leaf_id_collision", "entity_ids": ["shared"], "peer_names": ["a", "b"],
        "message": tree.warnings[0]["message"]}]
    assert "'shared'" in tree.warnings[0]["message"]


def test_areas_merge_by_id():
    tree = merge([robot("a", 1, "ha", [], {}, areas=("site",)), robot("b", 2, "hb", [], {}, areas=("site", "dock"))], 1)
    assert sorted(tree.items["areas"]) == ["dock", "site"]
    assert ("areas", "site") not in tree.routes and tree.routes[("areas", "dock")] == ("b", "dock")


def test_a_robot_that_is_away_is_retained_unavailable():
    tree = merge([robot("a", 1, "ha", ["ctl"], {"body": ["ctl"]}, available=False),
                  robot("b", 2, "hb", ["ctl"], {"body": ["ctl"]})], 1)
    app = tree.items["apps"]["ctl"]["x-medkit"]
    assert app["available"] is False and app["is_online"] is False
    assert tree.items["components"]["ha"]["x-medkit"]["available"] is False
    assert "available" not in tree.items["components"]["hb"]["x-medkit"]
    assert "available" not in tree.items["functions"]["body"]["x-medkit"]   # reachable through b


def test_listings_are_sorted_counted_and_serialized_once():
    tree = merge([robot("a", 1, "ha", ["z", "b", "m"], {})], 1)
    body = tree.listing("apps")
    assert tree.listing("apps") is body
    parsed = orjson.loads(body)
    assert [a["id"] for a in parsed["items"]] == ["b", "m", "z"] and parsed["x-medkit"] == {"total_count": 3}
    assert orjson.loads(tree.listing("areas")) == {"items": [], "x-medkit": {"total_count": 0}}
    assert tree.elsewhere("apps", "ha") == "Component" and tree.elsewhere("apps", "nothing") is None
    assert tree.entity("apps", "nothing") is None and tree.size == 4


def test_an_app_a_robot_lists_twice_is_taken_once():
    tree = merge([RobotTree("a", 1, True, {"areas": [], "components": [], "functions": [],
                                           "apps": [item("apps", "x"), item("apps", "x")]})], 1)
    assert list(tree.items["apps"]) == ["x"]


def test_a_tree_that_breaks_medkits_limits_is_not_taken():
    good = {"areas": [], "components": [], "apps": [{"id": "a"}], "functions": []}
    assert tree_problem(good) is None
    assert tree_problem([]) == "not a JSON object"
    assert "apps" in tree_problem({**good, "apps": "x"})
    assert "valid id" in tree_problem({**good, "apps": [{"id": "../etc/passwd"}]})
    assert "valid id" in tree_problem({**good, "apps": [{"name": "no id"}]})
    assert "1001 entities" in tree_problem({**good, "apps": [{"id": f"a{i}"} for i in range(1001)]})
