"""Fleet bench (issue 34): the fleet gateway over 500 simulated robots, and a real robot's cost of the link.

``make bench`` (``bench/run.py``) runs :func:`case` (rows ``fleet_faults``, ``fleet_hung``,
``fleet_fault_stream``, ``fleet_memory``, ``fleet_idle``); ``python -m bench.fleet [--quick]`` runs
the same alone and prints the rows as JSON.  Everything is started here, in the bench's ROS domain:

- a Zenoh router (``sovd-zenoh-router``);
- a real robot: the demo robot (``demo/robot.py``) and two gateways watching it, one with
  ``--fleet-link`` (``--fault-confirm-count 1``: a failing status is confirmed by its first report)
  and one without, the reference for the link's cost;
- the fleet gateway (``--fleet-aggregate``), measured before any robot joined (its reference memory);
- ``bench/fleetsim.py``: ``robots`` simulated robots answering from the real robot's recorded
  answers (its tree, ``/faults``), each after its own latency (2–20 ms; 5 % of them 60–120 ms).

Rows (each figure against a reference from the same run):

- ``fleet_faults``: ``GET /api/v1/faults`` on the fleet gateway, one connection, every robot asked;
  p50 against the real robot's own ``GET /faults`` p50.  Target: p50 ≤ 150 ms.
- ``fleet_hung``: the same with one robot hung (its token stays, it never answers): every answer
  comes at the robot's timeout and names it in ``failed_peers``, never later.  Target: max ≤
  ``fleet_timeout`` + 0.5 s.
- ``fleet_fault_stream``: a fault confirmed on the real robot to its event on the fleet gateway's
  ``/faults/stream``, from the event's own ``timestamp`` (the robot's clock is this machine's); the
  reference is the same event on the robot's own stream.  Target: p50 ≤ 50 ms.
- ``fleet_memory``: the fleet gateway's memory (USS of the supervisor, the fleet link and the HTTP
  side, summed) with ``robots`` robots merged, against the same gateway before any joined.  Report.
- ``fleet_idle``: the CPU of the robot gateway with the link on (in the fleet, pinged, its tree read)
  against the one with it off, over the same idle window.  Target: ≤ 1.1 × the link-off gateway.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import threading
import time
from typing import Any

import psutil
import requests

from bench.procs import cpu_seconds
from common.harness.diagpub import DiagPub
from common.harness.fleetsim import Router, SimFleet, record
from common.harness.gateway import FleetGateway, Gateway
from common.harness.procs import Proc, poll_until, private_ros_domain

TOKEN = "bench-fleet-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}

FULL = {"robots": 500, "requests": 60, "hung_requests": 10, "faults": 20, "idle_s": 60.0, "timeout": 2.0,
        "record_faults": True}
QUICK = {"robots": 20, "requests": 5, "hung_requests": 2, "faults": 3, "idle_s": 3.0, "timeout": 1.0,
         "record_faults": False}
TARGET_FAULTS_P50_MS = 150.0
TARGET_HUNG_EXTRA_S = 0.5
TARGET_STREAM_P50_MS = 50.0
TARGET_IDLE_RATIO = 1.1


def tree_cpu(gw: Gateway) -> float:
    """CPU seconds of a gateway's processes (the supervisor and everything under it)."""
    root = psutil.Process(gw.pid)
    total = 0.0
    for p in [root, *root.children(recursive=True)]:
        try:
            total += cpu_seconds(p)
        except psutil.NoSuchProcess:
            pass
    return total


def uss_mb(gw: Gateway) -> float:
    root = psutil.Process(gw.pid)
    total = 0
    for p in [root, *root.children(recursive=True)]:
        try:
            total += p.memory_full_info().uss
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            pass
    return total / 2**20


def timed_get(url: str, n: int) -> list[float]:
    out = []
    with requests.Session() as s:
        for _ in range(n):
            started = time.perf_counter()
            r = s.get(url, headers=AUTH, timeout=30)
            out.append((time.perf_counter() - started) * 1000)
            assert r.status_code == 200, r.text[:300]
    return out


class FaultEvents:
    """A ``/faults/stream`` read on a thread: ``(arrival, event)`` pairs, the arrival in wall-clock seconds."""

    def __init__(self, api: str, headers: dict[str, str] | None = None):
        self.response = requests.get(api + "/faults/stream", headers=headers or {}, stream=True, timeout=(10, 120))
        assert self.response.status_code == 200, self.response.text[:300]
        self.got: list[tuple[float, dict[str, Any]]] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        text = b""
        try:
            for data in self.response.iter_content(chunk_size=None):
                arrived = time.time()
                text += data
                while b"\n\n" in text:
                    block, _, text = text.partition(b"\n\n")
                    for line in block.split(b"\n"):
                        if line.startswith(b"data:"):
                            self.got.append((arrived, json.loads(line[5:])))
        except (requests.RequestException, ValueError, AttributeError):
            pass

    def wait(self, code: str, timeout: float = 30.0) -> tuple[float, dict[str, Any]]:
        def found():
            return next(((t, e) for t, e in self.got if e["fault"]["fault_code"] == code
                         and e["event_type"] == "fault_confirmed"), None)
        return poll_until(found, timeout, interval=0.01, message=code)

    def close(self) -> None:
        threading.Thread(target=self.response.close, daemon=True).start()


def stream_latencies(gw: Gateway, robot: Gateway, pub: DiagPub, trials: int) -> tuple[list[float], list[float]]:
    """A fault confirmed on the robot, seen on the fleet's stream and on the robot's own (ms after its timestamp)."""
    fleet_ms, robot_ms = [], []
    fleet_stream, robot_stream = FaultEvents(gw.api, AUTH), FaultEvents(robot.api)
    try:
        time.sleep(1.0)   # both streams open (their subscriptions confirmed) before the first fault
        for trial in range(trials):
            code = f"BENCH_FLEET_{trial}"
            pub.set([{"name": f"bench fleet {trial}", "level": 2, "message": "bad"}])
            for stream, out in ((fleet_stream, fleet_ms), (robot_stream, robot_ms)):
                arrived, event = stream.wait(code)
                out.append((arrived - event["timestamp"]) * 1000)
            pub.set([{"name": f"bench fleet {trial}", "level": 0, "message": "ok"}])
    finally:
        fleet_stream.close()
        robot_stream.close()
    return fleet_ms, robot_ms


def bare_fanout(endpoint: str, names: set[str], n: int, timeout: float) -> list[float]:
    """The reference of the fleet's GET /faults: the same wildcard query to the same robots from a bare
    Zenoh session in this process (no HTTP, no IPC, no merge): until every robot answered, in ms."""
    import zenoh

    from ipc import fleet as wire
    from supervisor.fleet.aggregator import Gather

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("client"))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    session = zenoh.open(conf)
    try:
        payload = wire.request("GET", wire.API + "/faults", "", dict(AUTH), b"", int(timeout * 1000))
        times = []
        for _ in range(n + 2):
            gather = Gather(set(names))
            started = time.perf_counter()
            gather.launch(session, wire.query_key("*", "faults"), payload, timeout)
            gather.wait(timeout + 0.05)
            times.append((time.perf_counter() - started) * 1000)
        return times[2:]   # (two to warm up, as the fleet's)
    finally:
        session.close()


def measure(p: dict[str, Any], work_dir: str) -> dict[str, Any]:
    procs: list[Any] = []
    out: dict[str, Any] = {"robots": p["robots"], "timeout_s": p["timeout"]}
    try:
        router = Router()
        procs.append(router)
        procs.append(Proc([sys.executable, "-m", "demo.robot"], name="demo robot",
                          log_path=os.path.join(work_dir, "fleet-demo.log")))
        robot = Gateway("--api-token", TOKEN, "--fleet-link", "--fleet-connect", router.endpoint, "--fleet-id",
                        "real_robot", "--fault-confirm-count", "1", "--fault-stale-s", "0", "--log-level", "warning",
                        log_path=os.path.join(work_dir, "fleet-robot.log"))
        procs.append(robot)
        alone = Gateway("--api-token", TOKEN, "--log-level", "warning",
                        log_path=os.path.join(work_dir, "fleet-robot-alone.log"))
        procs.append(alone)
        for gw in (robot, alone):
            poll_until(lambda gw=gw: len(gw.get("/apps").json()["items"]) >= 7, 60, interval=0.3,
                       message="the demo robot's nodes")
        gw = FleetGateway("--api-token", TOKEN, "--fleet-aggregate", "--fleet-connect", router.endpoint,
                          "--fleet-timeout", str(p["timeout"]), "--log-level", "warning",
                          log_path=os.path.join(work_dir, "fleet-gateway.log"))
        procs.append(gw)
        poll_until(lambda: [x["name"] for x in gw.get("/health").json()["peers"]] == ["real_robot"], 30,
                   interval=0.2, message="the real robot in the fleet")
        out["memory_alone_mb"] = uss_mb(gw)
        # record once the demo robot has a fault or two (its battery and its wheels report them)
        if p["record_faults"]:
            poll_until(lambda: robot.get("/faults", headers=AUTH).json()["items"], 120, interval=1.0,
                       message="a fault on the demo robot to record")
        answers = record(robot.api, TOKEN)
        sim = SimFleet(router, answers, p["robots"], slow=max(1, p["robots"] // 20), slow_ms=[60, 120],
                       latency_ms=[2, 20])
        procs.append(sim)
        total = p["robots"] + 1
        poll_until(lambda: gw.get("/health").json()["x-medkit-fleet"]["robots_online"] == total, 120,
                   interval=0.5, message=f"{total} robots online")
        poll_until(lambda: len(gw.get("/components", headers=AUTH).json()["items"]) == total, 300, interval=1.0,
                   message=f"{total} trees merged")
        out["entities"] = gw.get("/health").json()["x-medkit-fleet"]["tree_entities"]
        out["memory_mb"] = uss_mb(gw)
        # fleet GET /faults, and the robot's own as the reference
        timed_get(gw.api + "/faults", 2)
        out["faults_ms"] = timed_get(gw.api + "/faults", p["requests"])
        body = gw.get("/faults", headers=AUTH).json()
        out["faults_partial"] = body["x-medkit"].get("failed_peers", [])
        out["faults_items"] = len(body["items"])
        out["robot_faults_ms"] = timed_get(robot.api + "/faults", p["requests"])
        peers = {x["name"] for x in gw.get("/health").json()["peers"]}
        out["bare_faults_ms"] = bare_fanout(router.endpoint, peers, p["requests"], p["timeout"])
        # one robot hung
        sim.send("hang sim_0001")
        out["hung_ms"] = timed_get(gw.api + "/faults", p["hung_requests"])
        out["hung_failed"] = gw.get("/faults", headers=AUTH).json()["x-medkit"].get("failed_peers")
        sim.send("unhang sim_0001")
        # a fault on the real robot: to the fleet's stream, and to its own
        pub = DiagPub("bench_fleet", rate=10)
        procs.append(pub)
        out["stream_ms"], out["robot_stream_ms"] = stream_latencies(gw, robot, pub, p["faults"])
        # the robot's cost of being in the fleet, idle: both gateways over the same window
        time.sleep(2.0)
        before = {"on": tree_cpu(robot), "off": tree_cpu(alone)}
        started = time.monotonic()
        time.sleep(p["idle_s"])
        wall = time.monotonic() - started
        out["idle_cpu"] = {k: (tree_cpu(g) - before[k]) / wall for k, g in (("on", robot), ("off", alone))}
    finally:
        for proc in reversed(procs):
            try:
                proc.stop()
            except Exception as exc:  # noqa: BLE001 - stop the others
                print(f"stopping {getattr(proc, 'name', proc)}: {exc!r}", file=sys.stderr)
    return out


def rows(m: dict[str, Any]) -> list[dict[str, Any]]:
    """The bench's rows (``bench/run.py``'s ``add`` arguments) from one measurement."""
    n = m["robots"] + 1
    fleet, own = m["faults_ms"], m["robot_faults_ms"]
    fleet_p50, own_p50 = statistics.median(fleet), statistics.median(own)
    bare_p50 = statistics.median(m["bare_faults_ms"])
    hung = m["hung_ms"]
    stream_p50 = statistics.median(m["stream_ms"])
    robot_stream_p50 = statistics.median(m["robot_stream_ms"])
    idle = m["idle_cpu"]
    ratio = idle["on"] / idle["off"] if idle["off"] > 0 else None
    limit_ms = (m["timeout_s"] + TARGET_HUNG_EXTRA_S) * 1000
    return [
        dict(key="fleet_faults", case=f"fleet: GET /faults over {n} robots (1 real, {m['robots']} simulated)",
             how="one connection, every robot asked (one wildcard query); references: the real robot's own "
                 "GET /faults, and the same query from a bare Zenoh session (no HTTP, IPC or merge; 1 in 20 "
                 "simulated robots answers in 60-120 ms, the others in 2-20 ms)",
             values={"n": len(fleet), "p50_ms": round(fleet_p50, 1), "bare_p50_ms": round(bare_p50, 1),
                                        "p95_ms": round(sorted(fleet)[int(len(fleet) * 0.95) - 1], 1),
                                        "max_ms": round(max(fleet), 1), "robot_p50_ms": round(own_p50, 1),
                                        "items": m["faults_items"], "failed_peers": m["faults_partial"]},
             measured=f"p50 {fleet_p50:.0f} ms (bare Zenoh query {bare_p50:.0f} ms; robot alone {own_p50:.1f} ms), "
                      f"max {max(fleet):.0f} ms, "
                      f"{m['faults_items']} faults, failed {len(m['faults_partial'])}",
             target=f"p50 ≤ {TARGET_FAULTS_P50_MS:g} ms", passed=fleet_p50 <= TARGET_FAULTS_P50_MS),
        dict(key="fleet_hung", case=f"fleet: GET /faults over {n} robots, one of them hung",
             how="the hung robot keeps its token and never answers; every answer should come at fleet_timeout "
                 f"({m['timeout_s']:g} s) and name it in failed_peers",
             values={"n": len(hung), "p50_ms": round(statistics.median(hung), 1), "max_ms": round(max(hung), 1),
                     "failed_peers": m["hung_failed"]},
             measured=f"max {max(hung):.0f} ms, failed_peers {m['hung_failed']}",
             target=f"max ≤ fleet_timeout + {TARGET_HUNG_EXTRA_S:g} s",
             passed=max(hung) <= limit_ms and m["hung_failed"] == ["sim_0001"]),
        dict(key="fleet_fault_stream", case="fleet: a fault confirmed on a robot → the fleet's /faults/stream",
             how="from the event's timestamp (the robot confirms it; same machine, same clock) to its arrival "
                 "on the fleet gateway's stream; reference: the same event on the robot's own stream",
             values={"n": len(m["stream_ms"]), "p50_ms": round(stream_p50, 1), "max_ms": round(max(m["stream_ms"]), 1),
                     "robot_p50_ms": round(robot_stream_p50, 1)},
             measured=f"p50 {stream_p50:.1f} ms (robot's own stream {robot_stream_p50:.1f} ms)",
             target=f"p50 ≤ {TARGET_STREAM_P50_MS:g} ms", passed=stream_p50 <= TARGET_STREAM_P50_MS),
        dict(key="fleet_memory", case=f"fleet: the fleet gateway's memory with {n} robots' trees",
             how="USS of the supervisor, the fleet link and the HTTP side, summed; reference: the same gateway "
                 "with one robot, before the simulated ones joined",
             values={"mb": round(m["memory_mb"], 1), "alone_mb": round(m["memory_alone_mb"], 1),
                     "entities": m["entities"],
                     "kb_per_robot": round((m["memory_mb"] - m["memory_alone_mb"]) * 1024 / max(1, m["robots"]), 1)},
             measured=f"{m['memory_mb']:.0f} MB with {m['entities']} entities (with one robot "
                      f"{m['memory_alone_mb']:.0f} MB)"),
        dict(key="fleet_idle", case="fleet: a robot's CPU in the fleet, idle, against the same robot off it",
             how="CPU of two gateways' processes watching the same demo robot over the same window, one with "
                 "--fleet-link (in the fleet: pinged, its tree read), one without",
             values={"on": round(idle["on"] * 100, 2), "off": round(idle["off"] * 100, 2),
                     "ratio": round(ratio, 3) if ratio is not None else None},
             measured=f"{idle['on'] * 100:.2f}% vs {idle['off'] * 100:.2f}% of a core"
                      + (f" = {ratio:.2f} ×" if ratio is not None else ""),
             target=f"≤ {TARGET_IDLE_RATIO:g} × off", passed=ratio is not None and ratio <= TARGET_IDLE_RATIO),
    ]


def case(bench: Any) -> None:
    """``make bench``'s fleet rows (issue 34)."""
    m = measure(QUICK if bench.args.quick else FULL, bench.work_dir)
    bench.extra["fleet"] = m
    for row in rows(m):
        bench.add(row["key"], row["case"], row["how"], row["values"], row["measured"], row.get("target", "—"),
                  row.get("passed"))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bench.fleet")
    parser.add_argument("--quick", action="store_true", help="20 simulated robots, a few requests (smoke)")
    parser.add_argument("--robots", type=int, help="simulated robots (default 500, quick 20)")
    args = parser.parse_args(argv)
    private_ros_domain()
    p = dict(QUICK if args.quick else FULL)
    if args.robots:
        p["robots"] = args.robots
    import tempfile

    m = measure(p, tempfile.mkdtemp(prefix="sovd-bench-fleet-"))
    print(json.dumps({"rows": rows(m), "measured": m}, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
