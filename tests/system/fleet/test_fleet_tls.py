"""The fleet over TLS with access control: the example configurations of ``docs/fleet/`` as they are.

The certificates are made here (a CA of our own, ``tests/support/fleet.py``'s :func:`make_pki`); the
three files are read from ``docs/fleet/`` with only their paths and port replaced, so the
documented configuration is the tested one.  A robot (a real gateway with ``--fleet-link``) and the
fleet gateway connect with their certificates; then:

- the fleet works: the robot is learned, its tree merged, a read forwarded, a wildcard query answered;
- its events pass: a fault on the robot reaches the fleet's stream, a new node its tree (announced: the
  fleet gateway's backstop read is a day away);
- a session whose certificate the ACL names nowhere (same CA) learns nothing and gets no answer;
- no certificate, or one of another CA: no session at all;
- a robot cannot speak for another: a token under another robot's key is refused at the router.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from common.harness.diagpub import DiagPub
from common.harness.gateway import Gateway
from common.harness.procs import free_port, poll_until
from ipc import fleet as wire
from tests.support.fleet import AUTH, TOKEN, FleetGateway, Router, make_pki
from tests.support.rospub import RosNode
from tests.support.sse import EventStream

DOCS = Path(__file__).resolve().parents[3] / "docs" / "fleet"


def adapted(name: str, pki: Path, port: int) -> str:
    text = (DOCS / name).read_text()
    assert "/etc/sovd-gateway/fleet/" in text
    text = text.replace("/etc/sovd-gateway/fleet/", f"{pki}/")
    text = text.replace("tls/0.0.0.0:7447", f"tls/localhost:{port}").replace("tls/fleet.example.com:7447",
                                                                             f"tls/localhost:{port}")
    path = pki / name
    path.write_text(text)
    return str(path)


def session(pki: Path, port: int, stem: str | None, ca: str = "ca.pem"):
    import zenoh

    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("connect/endpoints", json.dumps([f"tls/localhost:{port}"]))
    tls = {"root_ca_certificate": str(pki / ca), "enable_mtls": True, "verify_name_on_connect": True}
    if stem:
        tls.update(connect_certificate=str(pki / f"{stem}.pem"), connect_private_key=str(pki / f"{stem}.key"))
    config.insert_json5("transport/link/tls", json.dumps(tls))
    config.insert_json5("connect/timeout_ms", "3000")
    return zenoh.open(config)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    pki = tmp_path_factory.mktemp("pki")
    make_pki(pki, {"router": "fleet-router", "robot": "robot_a", "robot_b": "robot_b",
                   "fleet-gateway": "fleet-gateway", "intruder": "intruder"})
    other = pki / "other"
    other.mkdir()
    make_pki(other, {"rogue": "fleet-gateway"})           # the right name, from another CA
    port = free_port()
    started = []
    try:
        router = Router(adapted("router.json5", pki, port), port=port, scheme="tls", host="localhost")
        started.append(router)
        started.append(RosNode({"node": "tls_marker", "publish": [
            {"topic": "tls_marker", "type": "std_msgs/msg/String", "rate": 5, "value": {"data": "over tls"}}]}))
        robot = Gateway("--workers", "1", "--api-token", TOKEN, "--fleet-link", "--fleet-id", "robot_a",
                        "--fleet-zenoh-config", adapted("robot.json5", pki, port))
        started.append(robot)
        # no backstop read of the trees: a change must come through the robot's announcement
        gw = FleetGateway("--workers", "1", "--api-token", TOKEN, "--fleet-aggregate", "--fleet-tree-refresh",
                          "86400", "--fleet-zenoh-config", adapted("fleet-gateway.json5", pki, port))
        started.append(gw)
        yield {"gw": gw, "robot": robot, "pki": pki, "port": port}
    finally:
        for proc in reversed(started):
            proc.stop()


def test_the_fleet_works_over_tls_with_access_control(fleet):
    gw = fleet["gw"]
    poll_until(lambda: gw.get("/apps/tls_marker/data/tls_marker", headers=AUTH).json()
               .get("data", {}).get("data") == "over tls", 60, interval=0.3, message="a read through the fleet")
    peers = gw.get("/health").json()["peers"]
    assert [(p["name"], p["status"]) for p in peers] == [("robot_a", "online")]
    body = gw.get("/faults", headers=AUTH).json()
    assert "partial" not in body["x-medkit"]
    # the fleet gateway's certificate may ask every robot at once (the fan-out's wildcard query)
    fleet_session = session(fleet["pki"], fleet["port"], "fleet-gateway")
    try:
        payload = wire.request("GET", "/api/v1/faults", headers=AUTH, budget_ms=3000)
        replies = [r.ok for r in fleet_session.get(wire.query_key("*", "faults"), payload=payload, timeout=5.0)
                   if r.ok is not None]
        assert [str(r.key_expr) for r in replies] == ["sovd/robot_a/read/faults"]
        assert wire.read_reply(replies[0].payload.to_bytes())[0] == 200
    finally:
        fleet_session.close()


def test_events_and_tree_changes_pass_the_access_control(fleet):
    gw = fleet["gw"]
    node = RosNode({"node": "tls_late", "publish": [
        {"topic": "tls_late", "type": "std_msgs/msg/String", "rate": 2, "value": {"data": "late"}}]})
    pub = DiagPub("tlspump", rate=5)
    try:
        poll_until(lambda: any(a["id"] == "tls_late" for a in gw.get("/apps", headers=AUTH).json()["items"]), 30,
                   interval=0.2, message="a node started later, in the fleet's tree")
        with EventStream(gw.port, "/api/v1/faults/stream", headers=AUTH) as stream:
            assert stream.status == 200
            pub.set([{"name": "tlspump: Pump", "level": 2, "message": "pressure lost"}])
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:
                event = stream.next(timeout=deadline - time.monotonic())
                if event and event["fault"]["fault_code"] == "TLSPUMP_PUMP":
                    break
            assert event["fault"]["x-medkit"]["contributors"] == ["peer:robot_a"]
    finally:
        pub.stop()
        node.stop()


def test_a_certificate_the_acl_does_not_name_learns_nothing_and_gets_no_answer(fleet):
    intruder = session(fleet["pki"], fleet["port"], "intruder")   # the fleet's CA: it connects
    try:
        tokens = list(intruder.liveliness().get("sovd/*/alive", timeout=2.0))
        assert [r for r in tokens if r.ok is not None] == []
        payload = wire.request("GET", "/api/v1/faults", headers=AUTH, budget_ms=3000)
        assert [r for r in intruder.get(wire.query_key("*", "faults"), payload=payload, timeout=2.0)
                if r.ok is not None] == []
        assert [r for r in intruder.get(wire.query_key("robot_a", "tree"), payload=payload, timeout=2.0)
                if r.ok is not None] == []
    finally:
        intruder.close()


def test_no_certificate_or_another_cas_is_no_session(fleet):
    import zenoh

    with pytest.raises(zenoh.ZError):
        session(fleet["pki"], fleet["port"], None)
    with pytest.raises(zenoh.ZError):
        session(fleet["pki"] / "other", fleet["port"], "rogue")


def test_a_robot_cannot_speak_for_another(fleet):
    gw = fleet["gw"]
    robot_a = session(fleet["pki"], fleet["port"], "robot")
    robot_b = session(fleet["pki"], fleet["port"], "robot_b")
    try:
        impostor = robot_a.liveliness().declare_token(wire.alive_key("robot_z"))
        honest = robot_b.liveliness().declare_token(wire.alive_key("robot_b"))
        poll_until(lambda: "robot_b" in {p["name"] for p in gw.get("/health").json()["peers"]}, 20, interval=0.2,
                   message="robot_b, declared after the impostor, learned")
        assert "robot_z" not in {p["name"] for p in gw.get("/health").json()["peers"]}
        impostor.undeclare()
        honest.undeclare()
    finally:
        robot_a.close()
        robot_b.close()
