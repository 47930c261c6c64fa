"""The fleet over Zenoh under trouble (issue 34): a router that goes away, robots that come and go.

Scenario A, the router restarts: a real robot (a gateway with ``--fleet-link`` and a ``/diagnostics``
publisher) and simulated robots (``common/harness/fleetsim.py``) are in the fleet; the router is stopped,
a fault is confirmed on the real robot while nobody can hear it, and a router is started again on
the same port.  What must hold: every robot is back in ``/health``, the fleet's answers are whole
again, and the fault confirmed during the outage reaches the fleet's stream, once (the fleet
gateway asks the robot for what it missed since its last event id).

Scenario B, churn: simulated robots leave and come back all the time (one of them hung) while
clients read the merged tree, fan out ``/faults`` and read robots' entities at once.  What must
hold: every answer is the contract's (200, or 504 ``not-responding`` for a robot that just left),
no fan-out answer comes later than the timeout allows, the fleet link is never restarted, and the
fleet view ends as it began.
"""

from __future__ import annotations

import random
import threading
import time

from common.harness.diagpub import DiagPub
from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from tests.reliability import load
from tests.support.fleet import AUTH, TOKEN, FleetGateway, Router, SimFleet
from tests.support.sse import EventStream
from tests.system.fleet.test_fleet_sim import recorded

TIMEOUT = 1.0
SIM_ROBOTS = load.scaled(20, 200)
CHURN_S = load.scaled(20, 180)
CLIENTS = load.scaled(4, 8)


def online(gw) -> int:
    return gw.get("/health").json()["x-medkit-fleet"]["robots_online"]


def test_a_router_restart_loses_no_robot_and_no_fault_event():
    started = []
    try:
        router = Router()
        started.append(router)
        robot = Gateway("--workers", "1", "--api-token", TOKEN, "--fleet-link", "--fleet-connect", router.endpoint,
                        "--fleet-id", "real_robot", "--fault-confirm-count", "1", "--fault-stale-s", "0")
        started.append(robot)
        pub = DiagPub("outage", rate=5)
        started.append(pub)
        sim = SimFleet(router, recorded(), SIM_ROBOTS, prefix="sim")
        started.append(sim)
        gw = FleetGateway("--api-token", TOKEN, "--fleet-aggregate", "--fleet-connect", router.endpoint,
                          "--fleet-timeout", str(TIMEOUT), "--fleet-tree-refresh", "86400")
        started.append(gw)
        total = SIM_ROBOTS + 1
        poll_until(lambda: online(gw) == total, 60, interval=0.3, message="every robot online")
        with EventStream(gw.port, "/api/v1/faults/stream", headers=AUTH, timeout=60) as stream:
            assert stream.status == 200
            # a fault the fleet hears as it happens, first
            pub.set([{"name": "outage: Before", "level": 2, "message": "heard"}])
            assert wait_code(stream, "OUTAGE_BEFORE", 30)
            router.stop()
            poll_until(lambda: not robot.get("/health").json()["x-medkit-fleet"]["session_open"]
                       or online(gw) < total, 30, interval=0.2, message="the link lost")
            pub.set([{"name": "outage: During", "level": 2, "message": "nobody hears it"}])
            poll_until(lambda: any(f["fault_code"] == "OUTAGE_DURING" for f in robot.get("/faults").json()["items"]),
                       30, interval=0.2, message="the fault confirmed on the robot during the outage")
            router = Router(port=router.port)
            started.append(router)
            poll_until(lambda: online(gw) == total, 120, interval=0.5, message="every robot back")
            event = wait_code(stream, "OUTAGE_DURING", 60)
            assert event["fault"]["x-medkit"]["contributors"] == ["peer:real_robot"]
            later = stream.collect(2.0)
            assert [e for e in later if e["fault"]["fault_code"] == "OUTAGE_DURING"
                    and e["event_type"] == "fault_confirmed"] == [], "taken twice"
        poll_until(lambda: "partial" not in gw.get("/faults", headers=AUTH).json()["x-medkit"], 60, interval=0.5,
                   message="whole answers again")
        load.record("fleet: router restart", note=f"{total} robots back; the outage's fault replayed once")
    finally:
        for proc in reversed(started):
            proc.stop()


def wait_code(stream: EventStream, code: str, timeout: float) -> dict | None:
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        event = stream.next(timeout=left)
        if event is None:
            return None
        if event["fault"]["fault_code"] == code and event["event_type"] == "fault_confirmed":
            return event
    raise AssertionError(f"no fault_confirmed of {code} within {timeout} s")


def test_robots_coming_and_going_under_load_keep_every_answer_in_the_contract():
    started = []
    try:
        router = Router()
        started.append(router)
        sim = SimFleet(router, recorded(), SIM_ROBOTS, hung=1)
        started.append(sim)
        gw = FleetGateway("--api-token", TOKEN, "--fleet-aggregate", "--fleet-connect", router.endpoint,
                          "--fleet-timeout", str(TIMEOUT), "--fleet-tree-refresh", "86400")
        started.append(gw)
        poll_until(lambda: online(gw) == SIM_ROBOTS, 60, interval=0.3, message="every robot online")
        poll_until(lambda: len(gw.get("/components", headers=AUTH).json()["items"]) == SIM_ROBOTS - 1, 60,
                   interval=0.3, message="the trees merged")
        link_pid = gw.fleet_link().pid
        names = [f"sim_{i:04d}" for i in range(SIM_ROBOTS - 1)]     # the hung one stays
        stop = threading.Event()
        answers: list[tuple[str, int, str, float]] = []
        lock = threading.Lock()

        def client(seed: int) -> None:
            rng = random.Random(seed)
            while not stop.is_set():
                path = rng.choice(["/faults", "/apps", "/components", f"/components/{rng.choice(names)}_host/faults",
                                   "/functions/body/data"])
                started_at = time.monotonic()
                r = gw.get(path, headers=AUTH, timeout=30)
                took = time.monotonic() - started_at
                code = r.json().get("error_code", "") if r.status_code != 200 else ""
                with lock:
                    answers.append((path, r.status_code, code, took))

        def churn() -> None:
            rng = random.Random(7)
            away: list[str] = []
            while not stop.is_set():
                if away and (len(away) > SIM_ROBOTS // 4 or rng.random() < 0.5):
                    sim.send("join " + away.pop(rng.randrange(len(away))))
                else:
                    name = rng.choice([n for n in names if n not in away])
                    sim.send("leave " + name)
                    away.append(name)
                stop.wait(rng.uniform(0.05, 0.3))
            for name in away:
                sim.send("join " + name)

        threads = [threading.Thread(target=client, args=(i,)) for i in range(CLIENTS)]
        threads.append(threading.Thread(target=churn))
        for t in threads:
            t.start()
        time.sleep(CHURN_S)   # the scenario's length: the load runs meanwhile
        stop.set()
        for t in threads:
            t.join(60)
        assert not any(t.is_alive() for t in threads)
        wrong = [a for a in answers if not (a[1] == 200 or (a[1] == 504 and a[2] == "not-responding"))]
        assert wrong == [], wrong[:10]
        late = [a for a in answers if a[3] > TIMEOUT + 2.5]
        assert late == [], late[:10]
        fanouts = [a for a in answers if a[0] == "/faults"]
        assert fanouts and all(a[1] == 200 for a in fanouts)
        assert gw.fleet_link().pid == link_pid
        poll_until(lambda: online(gw) == SIM_ROBOTS, 60, interval=0.3, message="every robot back")
        poll_until(lambda: all("available" not in c["x-medkit"] for c in gw.get("/components", headers=AUTH).json()
                               ["items"]), 60, interval=0.5, message="the fleet view as it began")
        load.record("fleet: churn", requests=len(answers),
                    statuses={f"{s}{' ' + c if c else ''}": sum(1 for a in answers if (a[1], a[2]) == (s, c))
                              for s, c in {(a[1], a[2]) for a in answers}},
                    worst_ms=max(a[3] for a in answers) * 1000,
                    note=f"{SIM_ROBOTS} robots, one hung, leaving and coming back; {CLIENTS} clients")
    finally:
        for proc in reversed(started):
            proc.stop()
