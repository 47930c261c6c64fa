"""A robot's fleet link (supervisor/fleet/robot.py) through a real gateway, asked over Zenoh directly.

The gateway (``--fleet-link``) starts while no router answers on its ``fleet_connect``: it boots and
serves its own API, and its link keeps trying until a router is started there.  Then a Zenoh session
of the test's own asks the robot what the fleet gateway would, and what it must not:

- a query whose key does not name its path's family, a write on a read key, a write with
  ``fleet_allow_writes`` off, a stream, a malformed envelope: refused with the contract's JSON error;
- the link's own reads (``tree``, ``events``, ``ping``): only to a valid identity;
- a trigger's events are published on ``sovd/<fleet_id>/events/triggers/<id>``.
"""

from __future__ import annotations

import json

import orjson
import pytest
import requests

from common.harness.gateway import Gateway
from common.harness.procs import free_port, poll_until
from ipc import fleet as wire
from tests.support.fleet import AUTH, TOKEN, Router
from tests.support.linepub import LinePublisher

ROBOT = "robot_l"


@pytest.fixture(scope="module")
def robot():
    port = free_port()
    gw = Gateway("--workers", "1", "--api-token", TOKEN, "--fleet-link", "--fleet-id", ROBOT,
                 "--fleet-connect", f"tcp/127.0.0.1:{port}")
    try:
        # before any router answers (whatever order the tests run in): what the robot says then
        yield {"gw": gw, "port": port, "apps_alone": gw.get("/apps").status_code,
               "fleet_alone": gw.get("/health").json()["x-medkit-fleet"]}
    finally:
        gw.stop()


@pytest.fixture(scope="module")
def session(robot):
    import zenoh

    router = Router(port=robot["port"])
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("connect/endpoints", json.dumps([router.endpoint]))
    s = zenoh.open(config)
    poll_until(lambda: [r for r in s.liveliness().get(wire.alive_key(ROBOT), timeout=1.0) if r.ok is not None], 30,
               interval=0.2, message="the robot's token once the router answers")
    yield s
    s.close()
    router.stop()


def ask(session, family: str, payload: bytes, write: bool = False) -> tuple[int, dict[str, str], bytes]:
    replies = [r for r in session.get(wire.query_key(ROBOT, family, write), payload=payload, timeout=5.0)]
    assert len(replies) == 1 and replies[0].ok is not None, replies
    return wire.read_reply(replies[0].ok.payload.to_bytes())


def test_a_robot_boots_without_its_router_and_joins_once_one_answers(robot):
    assert robot["apps_alone"] == 200                       # no router yet: the gateway serves its own API
    assert robot["fleet_alone"]["session_open"] is False


def test_its_link_keeps_trying_and_joins(robot, session):
    gw = robot["gw"]
    section = poll_until(lambda: (s := gw.get("/health").json()["x-medkit-fleet"])["session_open"] and s, 30,
                         interval=0.2, message="the session open")
    assert section["session_attempts"] >= 1


@pytest.mark.parametrize("family, payload, write, status, needle", [
    ("faults", wire.request("GET", "/api/v1/apps", headers=AUTH), False, 400, "is not the path's"),
    ("data", wire.request("PUT", "/api/v1/apps/x/data/t", headers=AUTH), False, 400, "does not go on a read key"),
    ("data", wire.request("PUT", "/api/v1/apps/x/data/t", headers=AUTH), True, 403,
     "Writes through the fleet are disabled on robot 'robot_l'"),
    ("faults", wire.request("GET", "/api/v1/faults/stream", headers=AUTH), False, 400, "streams are not carried"),
    ("faults", b"\x93\x01\x02\x03", False, 400, "malformed fleet request"),
    ("faults", wire.request("GET", "/metrics", headers=AUTH), False, 400, "malformed fleet request"),
])
def test_what_a_robot_refuses(session, family, payload, write, status, needle):
    got, headers, body = ask(session, family, payload, write)
    assert got == status and headers["Content-Type"] == "application/json"
    doc = orjson.loads(body)
    assert needle in doc["message"] and doc["parameters"]["fleet_id"] == ROBOT


def test_the_links_own_reads_need_an_identity(session):
    for family in ("tree", "events", "ping"):
        assert ask(session, family, wire.request("GET", "/api/v1/", after=0))[0] == 401
        assert ask(session, family, wire.request("GET", "/api/v1/", headers={"Authorization": "Bearer " + "x" * 20},
                                                  after=0))[0] == 401
    status, _, body = ask(session, "tree", wire.request("GET", "/api/v1/", headers=AUTH))
    tree = orjson.loads(body)
    assert status == 200 and tree["fleet_id"] == ROBOT and len(tree["components"]) == 1
    assert set(tree) == {"fleet_id", "areas", "components", "apps", "functions"}
    status, _, body = ask(session, "events", wire.request("GET", "/api/v1/", headers=AUTH, after=-1))
    assert status == 200 and orjson.loads(body)["events"] == [] and isinstance(orjson.loads(body)["next_id"], int)
    status, _, body = ask(session, "ping", wire.request("GET", "/api/v1/", headers=AUTH))
    assert status == 200 and orjson.loads(body)["fleet_id"] == ROBOT
    # a SOVD read, and the robot's own answer to a bad token
    assert ask(session, "discovery", wire.request("GET", "/api/v1/apps", headers=AUTH))[0] == 200
    assert ask(session, "discovery", wire.request("GET", "/api/v1/apps"))[0] == 401


def test_a_triggers_events_are_published_to_the_fleet(robot, session):
    gw = robot["gw"]
    pub = LinePublisher("fleet_trig", "/fleet_trig/value", "std_msgs/msg/Float64")
    got: list[dict] = []
    subscriber = session.declare_subscriber(wire.event_key(ROBOT, "triggers", "*"),
                                            lambda s: got.append({"key": str(s.key_expr),
                                                                  **orjson.loads(s.payload.to_bytes())}))
    try:
        poll_until(lambda: gw.get("/apps/fleet_trig").status_code == 200, 30, message="the app")
        r = requests.post(gw.api + "/apps/fleet_trig/triggers", headers=AUTH, timeout=10, json={
            "resource": "/api/v1/apps/fleet_trig/data/fleet_trig/value",
            "trigger_condition": {"condition_type": "OnChange"}, "multishot": True, "lifetime": 60})
        assert r.status_code == 201, r.text
        trigger = r.json()["id"]
        pub.wait_subscribers(1)
        for value in (1.0, 2.0):
            pub.send({"data": value})
        poll_until(lambda: len(got) >= 2, 20, interval=0.1, message="two trigger events over Zenoh")
        assert [e["payload"] for e in got[:2]] == [{"data": 1.0}, {"data": 2.0}]
        assert got[0]["key"] == f"sovd/{ROBOT}/events/triggers/{trigger}" and got[0]["trigger_id"] == trigger
    finally:
        subscriber.undeclare()
        pub.stop()
