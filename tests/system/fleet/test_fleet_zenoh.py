"""The fleet over Zenoh, for real (issue 34): three robots, one Zenoh router, one fleet gateway.

Each robot is a real gateway (``--fleet-link``) in a ROS domain of its own, with the demo robot
and a marker node that publishes the robot's own name on ``/fleet/marker`` (so a read shows which
robot answered).  ``sovd-zenoh-router`` is the router; the fleet gateway (``--fleet-aggregate``) has
no ROS worker.  All three robots run on this one host, so their host components collide (medkit's
``leaf_id_collision``), and their apps do (``<fleet_id>__<id>``).  Checked, through the fleet gateway:

- ``/health`` lists the robots with their link state and latency;
- the merged tree: one app per robot and node, renamed on collision, each naming its robot;
- a data read reaches the robot that owns the app; a function several robots offer is fanned out;
- a fault on one robot is in the fleet's ``/faults`` (named for that robot) and on its stream, and
  ``Last-Event-ID`` replays it;
- every request needs an identity, at the fleet gateway and at the robot itself;
- writes pass only where both sides allow them;
- a robot whose link is frozen, and then a robot killed in the middle of a request, are in
  ``failed_peers`` within the fleet timeout, and a killed robot's apps stay listed, unavailable.
"""

from __future__ import annotations

import os
import sys
import threading
import time

import psutil
import pytest
import requests

from common.harness.diagpub import DiagPub
from common.harness.gateway import Gateway
from common.harness.procs import Proc, claim_domain, poll_until
from tests.support.fleet import AUTH, TOKEN, FleetGateway, Router
from tests.support.metrics import parse, value
from tests.support.rospub import RosNode
from tests.support.sse import EventStream

ROBOTS = ("robot_a", "robot_b", "robot_c")
TIMEOUT = 1.5                 # --fleet-timeout: what one robot gets to answer
BOUND = TIMEOUT + 2.0         # a generous bound on a fan-out's answer (catches a hang, times nothing)


@pytest.fixture(scope="module")
def fleet():
    domains = [int(os.environ["ROS_DOMAIN_ID"]), claim_domain(), claim_domain()]
    started: list = []
    try:
        router = Router()
        started.append(router)
        robots = {}
        for name, domain in zip(ROBOTS, domains, strict=True):
            env = {"ROS_DOMAIN_ID": str(domain)}
            started.append(Proc([sys.executable, "-m", "demo.robot"], env=env, name=f"demo {name}"))
            started.append(RosNode({"node": "marker", "namespace": "/fleet", "publish": [
                {"topic": "marker", "type": "std_msgs/msg/String", "rate": 5, "value": {"data": name}}]},
                env=env))
            writes = ("--allow-publish", "--fleet-allow-writes") if name == "robot_a" else ()
            robots[name] = Gateway("--workers", "1", "--api-token", TOKEN, "--fleet-link", "--fleet-connect",
                                   router.endpoint, "--fleet-id", name, "--fault-confirm-count", "2",
                                   "--fault-stale-s", "0", *writes, env=env)
            started.append(robots[name])
        gw = FleetGateway("--api-token", TOKEN, "--fleet-aggregate", "--fleet-connect", router.endpoint,
                          "--fleet-timeout", str(TIMEOUT), "--fleet-allow-writes",
                          "--fleet-tree-refresh", "86400")   # a tree change must come by its announcement
        started.append(gw)
        poll_until(lambda: len(markers(gw)) == 3 and all(read_marker(gw, a) for a in markers(gw)), 90,
                   interval=0.5, message="every robot's marker readable through the fleet")
        yield {"gw": gw, "robots": robots, "router": router, "domains": dict(zip(ROBOTS, domains, strict=True))}
    finally:
        for proc in reversed(started):
            proc.stop()


def markers(gw) -> dict[str, str]:
    """The fleet's marker apps: app id -> the robot it names in ``contributors``."""
    r = gw.get("/apps", headers=AUTH)
    if r.status_code != 200:
        return {}
    return {a["id"]: a["x-medkit"]["contributors"][0].removeprefix("peer:") for a in r.json()["items"]
            if a["id"] == "marker" or a["id"].endswith("__marker")}


def read_marker(gw, app_id: str) -> str | None:
    r = gw.get(f"/apps/{app_id}/data/fleet/marker", headers=AUTH)
    return r.json()["data"]["data"] if r.status_code == 200 and r.json()["x-medkit"]["status"] == "data" else None


def fanout(gw, path: str) -> tuple[dict, float]:
    started = time.monotonic()
    r = gw.get(path, headers=AUTH, timeout=30)
    assert r.status_code == 200, r.text
    return r.json(), time.monotonic() - started


def test_health_lists_every_robot_with_its_link_state_and_latency(fleet):
    body = fleet["gw"].get("/health").json()
    assert body["status"] == "healthy"
    peers = {p["name"]: p for p in body["peers"]}
    assert set(peers) == set(ROBOTS)
    for peer in peers.values():
        assert peer["status"] == "online" and peer["url"] == f"zenoh:sovd/{peer['name']}"
        assert isinstance(peer["latency_ms"], float) and peer["latency_ms"] >= 0
        assert peer["entities"] > 0
    assert body["x-medkit-fleet"]["robots_online"] == 3 and body["x-medkit-fleet"]["session_open"] is True
    assert requests.get(fleet["gw"].url + "/api/v1/", timeout=10).json()["capabilities"]["aggregation"] is True
    # per robot in /metrics, labelled by robot (as many as fleet_max_robots at most)
    scrape = parse(requests.get(fleet["gw"].url + "/metrics", timeout=10).text)
    assert value(scrape, "sovd_fleet_link_up") == 1 and value(scrape, "sovd_fleet_robots_online") == 3
    for robot in ROBOTS:
        assert value(scrape, "sovd_fleet_robot_up", robot=robot) == 1
        assert value(scrape, "sovd_fleet_robot_queries", "sovd_fleet_robot_queries_total", robot=robot) >= 1
    assert "sovd_ros_worker_up" not in scrape      # the fleet gateway runs no ROS worker
    # a robot shows its own link in /health and /metrics
    robot = fleet["robots"]["robot_a"]
    section = robot.get("/health").json()["x-medkit-fleet"]
    assert section["session_open"] is True and section["queries_answered"] >= 1
    robot_scrape = parse(requests.get(robot.url + "/metrics", timeout=10).text)
    assert value(robot_scrape, "sovd_fleet_link_up") == 1
    assert value(robot_scrape, "sovd_fleet_queries_answered", "sovd_fleet_queries_answered_total") >= 1


def test_the_merged_tree_renames_colliding_apps_and_merges_the_host_and_functions(fleet):
    gw = fleet["gw"]
    found = markers(gw)
    # medkit's rule: the robot merged first keeps the id; the others' are <fleet_id>__<id>
    bare = [a for a in found if a == "marker"]
    assert len(bare) == 1 and sorted(found.values()) == sorted(ROBOTS)
    for app_id, robot in found.items():
        assert app_id == "marker" or app_id == f"{robot}__marker"
    apps = {a["id"]: a for a in gw.get("/apps", headers=AUTH).json()["items"]}
    for app_id, robot in found.items():
        assert apps[app_id]["x-medkit"]["source"] == f"peer:{robot}"
        assert apps[app_id]["href"] == f"/api/v1/apps/{app_id}"
    # Every robot runs the demo, so each of its apps is there once per robot.
    assert sum(1 for a in apps if a == "temp_sensor" or a.endswith("__temp_sensor")) == 3
    # The three share this host: one component, all three contributors, and medkit's warning.
    components = gw.get("/components", headers=AUTH).json()["items"]
    assert len(components) == 1
    assert components[0]["x-medkit"]["contributors"] == [f"peer:{r}" for r in ROBOTS]
    warnings = gw.get("/health").json()["warnings"]
    assert [w["code"] for w in warnings] == ["leaf_id_collision"]
    assert warnings[0]["entity_ids"] == [components[0]["id"]] and sorted(warnings[0]["peer_names"]) == list(ROBOTS)
    # A function several robots offer: merged, its hosts remapped to the fleet's app ids.
    function = gw.get("/functions/fleet", headers=AUTH).json()
    assert sorted(function["x-medkit"]["hosts"]) == sorted(found)
    assert function["x-medkit"]["contributors"] == [f"peer:{r}" for r in ROBOTS]
    hosts = gw.get("/functions/fleet/hosts", headers=AUTH).json()
    assert sorted(h["id"] for h in hosts["items"]) == sorted(found)


def test_a_data_read_reaches_the_robot_that_owns_the_app(fleet):
    gw = fleet["gw"]
    for app_id, robot in markers(gw).items():
        assert read_marker(gw, app_id) == robot
    # A forwarded answer is the robot's own (medkit forwards verbatim): its own id for the app.
    detail = gw.get("/apps/robot_b__marker" if "robot_b__marker" in markers(gw) else "/apps/marker",
                    headers=AUTH).json()
    assert detail["id"] == "marker"


def test_a_function_several_robots_offer_is_fanned_out_to_them(fleet):
    gw = fleet["gw"]
    body, _ = fanout(gw, "/functions/fleet/data")
    assert "partial" not in body["x-medkit"] and body["x-medkit"]["entity_id"] == "fleet"
    items = [i for i in body["items"] if i["id"] == "/fleet/marker"]
    assert sorted(i["x-medkit"]["contributors"][0] for i in items) == [f"peer:{r}" for r in ROBOTS]
    # member_ids name the apps as the fleet does (a renamed app under its fleet id)
    assert sorted(m for i in items for m in i["x-medkit"]["member_ids"]) == sorted(markers(gw))
    # An item under it names no single robot.
    r = gw.get("/functions/fleet/data/fleet/marker", headers=AUTH)
    assert r.status_code == 400 and "spans several robots" in r.json()["message"]


def test_every_request_needs_an_identity_at_the_fleet_and_at_the_robot(fleet):
    gw = fleet["gw"]
    assert gw.get("/apps").status_code == 401
    assert gw.get("/apps/marker", headers={"Authorization": "Bearer wrong-token-0123456789"}).status_code == 401
    assert gw.get("/faults").status_code == 401
    with EventStream(gw.port, "/api/v1/faults/stream") as refused:
        assert refused.status == 401
    # The robot checks what reaches it over the fleet, whoever sent it: a Zenoh session of our own.
    import zenoh

    from ipc import fleet as wire

    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("connect/endpoints", f'["{fleet["router"].endpoint}"]')
    session = zenoh.open(config)
    try:
        def ask(headers: dict) -> int:
            payload = wire.request("GET", "/api/v1/faults", headers=headers, budget_ms=3000)
            replies = list(session.get(wire.query_key("robot_a", "faults"), payload=payload, timeout=5.0))
            assert len(replies) == 1 and replies[0].ok is not None
            return wire.read_reply(replies[0].ok.payload.to_bytes())[0]

        assert ask({}) == 401
        assert ask({"Authorization": "Bearer wrong-token-0123456789"}) == 401
        assert ask(AUTH) == 200
    finally:
        session.close()
    # Locally, the robot's reads stay as open as they were.
    assert fleet["robots"]["robot_a"].get("/faults").status_code == 200


def test_writes_pass_only_where_both_sides_allow_them(fleet):
    gw = fleet["gw"]
    robot_of = {robot: app for app, robot in markers(gw).items()}
    controller = {r: robot_of[r].replace("marker", "controller") for r in ROBOTS}
    body = {"type": "std_msgs/msg/Bool", "data": {"data": True}}
    r = gw.put(f"/apps/{controller['robot_a']}/data/body/lights/command", json=body, headers=AUTH)
    assert r.status_code == 200, r.text
    poll_until(lambda: gw.get(f"/apps/{controller['robot_a']}/data/body/lights/state", headers=AUTH)
               .json()["data"]["data"] == "on", 20, interval=0.2, message="the light switched on robot_a")
    r = gw.put(f"/apps/{controller['robot_b']}/data/body/lights/command", json=body, headers=AUTH)
    assert r.status_code == 403 and "robot 'robot_b'" in r.json()["message"], r.text
    assert gw.put(f"/apps/{controller['robot_a']}/data/body/lights/command", json=body).status_code == 401


def next_fault(stream: EventStream, code: str, kind: str, timeout: float) -> tuple[str, dict]:
    """The id and data of the next event of fault ``code`` of ``kind`` on the stream."""
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        event = stream.next(timeout=left)
        assert event is not None, "the stream ended"
        if event["fault"]["fault_code"] == code and event["event_type"] == kind:
            return stream.fields[len(stream.events) - 1]["id"], event
    raise AssertionError(f"no {kind} of {code} within {timeout} s")


def test_a_fault_on_one_robot_is_in_the_fleets_faults_and_on_its_stream(fleet):
    gw = fleet["gw"]
    pub = DiagPub("fleetpump", rate=5, env={"ROS_DOMAIN_ID": str(fleet["domains"]["robot_b"])})
    try:
        with EventStream(gw.port, "/api/v1/faults/stream", headers=AUTH) as stream:
            assert stream.status == 200
            pub.set([{"name": "fleetpump: Pump", "level": 2, "message": "pressure lost"}])
            event_id, event = next_fault(stream, "FLEETPUMP_PUMP", "fault_confirmed", 30)
        assert event["fault"]["x-medkit"]["contributors"] == ["peer:robot_b"]
        listed = [f for f in gw.get("/faults", headers=AUTH).json()["items"] if f["fault_code"] == "FLEETPUMP_PUMP"]
        assert len(listed) == 1 and listed[0]["x-medkit"]["contributors"] == ["peer:robot_b"]
        assert listed[0]["status"] == "CONFIRMED"
        # Last-Event-ID: what came after an id is sent again
        with EventStream(gw.port, "/api/v1/faults/stream",
                         headers={**AUTH, "Last-Event-ID": str(int(event_id) - 1)}) as again:
            assert again.next(timeout=10) == event and again.fields[0]["id"] == event_id
    finally:
        pub.stop()


def gateway_processes(gw: Gateway) -> list[psutil.Process]:
    root = psutil.Process(gw.pid)
    return [root, *root.children(recursive=True)]


def fleet_link_of(gw: Gateway) -> psutil.Process:
    return next(p for p in gateway_processes(gw) if any("fleetlink" in part for part in p.cmdline()))


def test_x_the_supervisor_restarts_a_robots_killed_link_and_the_fleet_sees_it_come_back(fleet):
    gw, robot = fleet["gw"], fleet["robots"]["robot_a"]
    link = fleet_link_of(robot)
    link.kill()
    poll_until(lambda: {p["name"]: p["status"] for p in gw.get("/health").json()["peers"]}["robot_a"] == "offline",
               20, interval=0.1, message="robot_a offline")
    assert robot.get("/apps").status_code == 200        # the robot itself goes on serving its own API
    poll_until(lambda: {p["name"]: p["status"] for p in gw.get("/health").json()["peers"]}["robot_a"] == "online",
               30, interval=0.2, message="robot_a back online")
    assert fleet_link_of(robot).pid != link.pid
    poll_until(lambda: read_marker(gw, dict((v, k) for k, v in markers(gw).items())["robot_a"]) == "robot_a", 20,
               interval=0.2, message="robot_a read through the fleet again")


def test_y_a_robot_whose_link_is_silent_is_in_failed_peers_within_the_timeout(fleet):
    gw, silent = fleet["gw"], fleet["robots"]["robot_b"]
    link = fleet_link_of(silent)
    link.suspend()     # its Zenoh session stays up at the router: queries reach it and get no answer
    try:
        body, took = fanout(gw, "/faults")
        assert body["x-medkit"]["partial"] is True and body["x-medkit"]["failed_peers"] == ["robot_b"]
        assert TIMEOUT * 0.8 <= took < BOUND, took
        robots = {i["x-medkit"]["contributors"][0] for i in body["items"]}
        assert "peer:robot_b" not in robots
        # a request to one of its apps: 504 after its timeout, not a hang
        started = time.monotonic()
        r = gw.get(f"/apps/{dict((v, k) for k, v in markers(gw).items())['robot_b']}", headers=AUTH)
        assert r.status_code == 504 and r.json()["error_code"] == "not-responding"
        assert time.monotonic() - started < BOUND
    finally:
        link.resume()
    poll_until(lambda: "partial" not in fanout(gw, "/faults")[0]["x-medkit"], 30, interval=0.5,
               message="robot_b answering again")


def test_z_a_robot_killed_mid_request_is_in_failed_peers_within_the_timeout(fleet):
    gw, victim = fleet["gw"], fleet["robots"]["robot_c"]
    procs = gateway_processes(victim)
    http = [p for p in procs if "gunicorn" in " ".join(p.cmdline())]
    for p in http:
        p.suspend()   # its link takes the query and waits on the robot's own gateway: mid-request
    result: dict = {}

    def ask():
        result["body"], result["took"] = fanout(gw, "/faults")

    asking = threading.Thread(target=ask)
    asking.start()
    time.sleep(0.3)   # the query is out: the robot's link holds it (nothing is timed by this)
    for p in procs:
        try:
            p.kill()
        except psutil.NoSuchProcess:
            pass
    asking.join(BOUND + 5)
    assert not asking.is_alive()
    assert result["body"]["x-medkit"]["failed_peers"] == ["robot_c"] and result["body"]["x-medkit"]["partial"]
    assert result["took"] < BOUND, result["took"]
    assert {i["x-medkit"]["contributors"][0] for i in result["body"]["items"]} <= {"peer:robot_a", "peer:robot_b"}
    # the fleet sees it go; its apps stay listed, unavailable, and are answered 504 at once
    poll_until(lambda: {p["name"]: p["status"] for p in gw.get("/health").json()["peers"]}["robot_c"] == "offline",
               30, interval=0.3, message="robot_c offline")
    app_id = dict((v, k) for k, v in markers(gw).items())["robot_c"]
    poll_until(lambda: next(a for a in gw.get("/apps", headers=AUTH).json()["items"] if a["id"] == app_id)
               ["x-medkit"].get("available") is False, 10, interval=0.3, message="robot_c's apps unavailable")
    started = time.monotonic()
    r = gw.get(f"/apps/{app_id}/data/fleet/marker", headers=AUTH)
    assert r.status_code == 504 and "not connected" in r.json()["message"]
    assert time.monotonic() - started < TIMEOUT
    body, took = fanout(gw, "/faults")   # medkit asks only the robots that are there
    assert "partial" not in body["x-medkit"] and took < BOUND
