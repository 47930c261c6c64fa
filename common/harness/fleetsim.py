"""Many simulated robots in one process, on the fleet's Zenoh wire (issue 34's bench and tests).

Run as ``python -m common.harness.fleetsim '<json spec>'``::

    {"connect": "tcp/127.0.0.1:7447", "robots": 500, "answers": "/tmp/answers.json", "prefix": "sim",
     "latency_ms": [2, 20], "slow": 10, "slow_ms": [60, 120], "hung": 1, "seed": 1}

Each robot ``<prefix>_<nnnn>`` is what a robot's fleet link is to the fleet gateway
(``supervisor/fleet/robot.py``): a liveliness token ``sovd/<id>/alive`` and queryables on
``sovd/<id>/read/**`` and ``.../write/**``, answering from ``answers``, recorded from a real gateway
(:func:`record`), with the robot's host component renamed ``<id>_host`` so the robots do not
collide (in the answers and in the paths asked); the link's own ``tree``, ``events`` and ``ping`` reads are composed the same way.  Each robot
answers after its own latency, drawn uniformly from ``latency_ms`` (``slow_ms`` for the first
``slow`` robots); the last ``hung`` robots keep their token and never answer (a frozen link).  All
robots share one Zenoh session, and replies leave from one timer thread, never from Zenoh's callbacks.

Commands on stdin, one per line (the tests and the bench steer it this way):

- ``fault <robot> <id> <code>``: record fault event ``<id>`` (``fault_confirmed`` of ``<code>``) and
  publish it on ``sovd/<robot>/events/faults``; ``miss ...``: record it without publishing (a lost
  event: the fleet gateway gets it on its next catch-up);
- ``leave <robot>`` / ``join <robot>``: undeclare / declare again its token and queryables;
- ``hang <robot>`` / ``unhang <robot>``: it stops answering (its token stays), or answers again;
- ``tree <robot>``: announce a change of its tree.

Prints ``READY`` once every robot is declared and ``OK <command>`` after each command.

For the bench and the tests alike (the fleet's processes, with :mod:`common.harness.procs`):
:class:`Router` (``sovd-zenoh-router`` on a free port) and :class:`SimFleet` (this program, steered).
"""

from __future__ import annotations

import heapq
import json
import random
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import orjson

from ipc import fleet as wire

from .procs import Proc, free_port

BIN = Path(sys.executable).parent

TREE = ("areas", "components", "apps", "functions")
HELD_MAX = 100_000        # queries a hung robot holds (the oldest let go first)


def record(api: str, token: str, paths: tuple[str, ...] = ("/faults", "/faults?status=all")) -> dict[str, Any]:
    """A real gateway's answers, for :class:`Fleet`: the tree's four listings and ``paths``."""
    import requests

    headers = {"Authorization": f"Bearer {token}"}
    answers: dict[str, Any] = {}
    for path in (*(f"/{c}" for c in TREE), *paths):
        r = requests.get(api + path, headers=headers, timeout=10)
        answers[wire.API + path] = {"status": r.status_code, "body": r.text}
    host = orjson.loads(answers[wire.API + "/components"]["body"])["items"][0]["id"]
    return {"host": host, "answers": answers}


class Robot:
    def __init__(self, name: str, latency: float, hung: bool, fleet: Fleet):
        self.name, self.latency, self.hung, self.fleet = name, latency, hung, fleet
        self.events: list[dict[str, Any]] = []
        self.declared: list[Any] = []
        self.publisher = None

    def join(self, session) -> None:
        self.declared = [session.liveliness().declare_token(wire.alive_key(self.name)),
                         *(session.declare_queryable(k, self.on_query) for k in wire.queryable_keys(self.name))]
        self.publisher = session.declare_publisher(wire.event_key(self.name, "faults"))

    def leave(self) -> None:
        for entity in (*self.declared, self.publisher):
            if entity is not None:
                entity.undeclare()
        self.declared, self.publisher = [], None

    def on_query(self, query) -> None:
        kind, family = wire.query_parts(str(query.key_expr))
        key = wire.query_key(self.name, family, kind == "write")
        if self.hung:
            self.fleet.hold(query)
            return
        try:
            req = wire.read_request(query.payload.to_bytes() if query.payload is not None else b"")
            frame = self.answer(req, family)
        except wire.WireError as exc:
            frame = wire.error_reply(400, "invalid-request", str(exc))
        self.fleet.later(self.latency, query, key, frame)

    def answer(self, req: dict[str, Any], family: str) -> bytes:
        fleet = self.fleet
        if family == "tree":
            tree = {"fleet_id": self.name}
            for collection in TREE:
                tree[collection] = orjson.loads(fleet.body(self.name, f"{wire.API}/{collection}"))["items"]
            return wire.reply(200, orjson.dumps(tree), {"Content-Type": "application/json"})
        if family == "ping":
            return wire.reply(200, orjson.dumps({"fleet_id": self.name, "version": "sim"}))
        if family == "events":
            after = req.get("after", -1)
            events = [e for e in self.events if after >= 0 and e["id"] > after]
            next_id = (self.events[-1]["id"] + 1) if self.events else 1
            return wire.reply(200, orjson.dumps({"events": events, "next_id": next_id}))
        path = req["p"].replace(f"/{self.name}_host", f"/{fleet.host}") + ("?" + req["q"] if req["q"] else "")
        recorded = fleet.answers.get(path)
        if recorded is None:
            return wire.error_reply(404, "resource-not-found", "Resource not found", path=req["p"])
        return wire.reply(recorded["status"], fleet.body(self.name, path).encode(),
                          {"Content-Type": "application/json"})

    def fault(self, event_id: int, code: str, publish: bool) -> None:
        now = time.time()
        event = {"id": event_id, "event_type": "fault_confirmed", "timestamp": now, "fault": {
            "fault_code": code, "severity": 2, "description": "simulated", "first_occurred": now,
            "last_occurred": now, "occurrence_count": 1, "status": "CONFIRMED",
            "reporting_sources": ["/diagnostics"], "severity_label": "ERROR"}}
        self.events.append(event)
        if publish:
            self.publisher.put(orjson.dumps(event))


class Fleet:
    def __init__(self, spec: dict[str, Any]):
        recorded = json.load(open(spec["answers"])) if isinstance(spec["answers"], str) else spec["answers"]
        self.answers: dict[str, Any] = recorded["answers"]
        self.host = recorded["host"]
        self._host = re.compile(r'(?<=["/])' + re.escape(recorded["host"]) + r'(?=["/])')
        rng = random.Random(spec.get("seed", 1))
        n, slow, hung = spec["robots"], spec.get("slow", 0), spec.get("hung", 0)
        low, high = spec.get("latency_ms", [2, 20])
        slow_low, slow_high = spec.get("slow_ms", [60, 120])
        prefix = spec.get("prefix", "sim")
        self.robots: dict[str, Robot] = {}
        for i in range(n):
            name = f"{prefix}_{i:04d}"
            latency = rng.uniform(slow_low, slow_high) if i < slow else rng.uniform(low, high)
            self.robots[name] = Robot(name, latency / 1000.0, i >= n - hung, self)
        self._heap: list[tuple[float, int, Any, str, bytes]] = []
        self._seq = 0
        self._cv = threading.Condition()
        self._held: list[Any] = []
        self.session = None

    def body(self, robot: str, path: str) -> str:
        return self._host.sub(f"{robot}_host", self.answers[path]["body"])

    def hold(self, query) -> None:
        with self._cv:
            self._held.append(query)
            if len(self._held) > HELD_MAX:
                del self._held[: len(self._held) - HELD_MAX]

    def later(self, seconds: float, query, key: str, frame: bytes) -> None:
        with self._cv:
            self._seq += 1
            heapq.heappush(self._heap, (time.monotonic() + seconds, self._seq, query, key, frame))
            self._cv.notify()

    def _replier(self) -> None:
        while True:
            with self._cv:
                while not self._heap or self._heap[0][0] > time.monotonic():
                    self._cv.wait(None if not self._heap else max(0.0, self._heap[0][0] - time.monotonic()))
                _, _, query, key, frame = heapq.heappop(self._heap)
            try:
                query.reply(key, frame)
            except Exception as exc:  # the querier gave up meanwhile
                print(f"reply failed: {exc}", file=sys.stderr, flush=True)
            del query

    def start(self, connect: str) -> None:
        import zenoh

        config = zenoh.Config()
        config.insert_json5("mode", '"client"')
        config.insert_json5("scouting/multicast/enabled", "false")
        config.insert_json5("connect/endpoints", json.dumps([connect]))
        self.session = zenoh.open(config)
        threading.Thread(target=self._replier, name="replier", daemon=True).start()
        for robot in self.robots.values():
            robot.join(self.session)

    def command(self, line: str) -> None:
        words = line.split()
        verb, robot = words[0], self.robots[words[1]]
        if verb in ("fault", "miss"):
            robot.fault(int(words[2]), words[3], publish=verb == "fault")
        elif verb == "leave":
            robot.leave()
        elif verb == "join":
            robot.join(self.session)
        elif verb in ("hang", "unhang"):
            robot.hung = verb == "hang"
        elif verb == "tree":
            self.session.put(wire.event_key(robot.name, "tree"), b'{"generation": 0}')
        else:
            raise ValueError(verb)


class Router(Proc):
    """``sovd-zenoh-router`` on a free port; with ``config``, that file says where it listens (``port``)."""

    def __init__(self, config: str | None = None, port: int | None = None, scheme: str = "tcp",
                 host: str = "127.0.0.1"):
        self.port = port or free_port()
        self.endpoint = f"{scheme}/{host}:{self.port}"
        args = ["--config", config] if config else ["--listen", self.endpoint]
        super().__init__([str(BIN / "sovd-zenoh-router"), *args], name="zenoh router")
        self.wait_line(lambda line: line.startswith("ready "), 30)


class SimFleet(Proc):
    """Simulated robots (``common/harness/fleetsim.py``) on ``router``; ``answers`` as :func:`record` makes."""

    def __init__(self, router: Router, answers: dict, robots: int, **spec):
        self.answers_file = tempfile.NamedTemporaryFile("w", suffix=".json", delete=False)  # noqa: SIM115
        json.dump(answers, self.answers_file)
        self.answers_file.close()
        full = {"connect": router.endpoint, "robots": robots, "answers": self.answers_file.name, **spec}
        super().__init__([sys.executable, "-m", "common.harness.fleetsim", json.dumps(full)], name="fleet simulator",
                         stdin=subprocess.PIPE)
        self.wait_line(lambda line: line == "READY", 60)

    def send(self, command: str, timeout: float = 10.0) -> None:
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()
        self.wait_line(lambda line: line in (f"OK {command}",) or line.startswith(f"ERROR {command}"), timeout)


def main() -> None:
    spec = json.loads(sys.argv[1])
    fleet = Fleet(spec)
    fleet.start(spec["connect"])
    print("READY", flush=True)
    for line in sys.stdin:
        line = line.strip()
        if not line:
            continue
        try:
            fleet.command(line)
            print(f"OK {line}", flush=True)
        except (KeyError, ValueError, IndexError) as exc:
            print(f"ERROR {line}: {exc}", flush=True)


if __name__ == "__main__":
    main()
