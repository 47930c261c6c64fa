"""The fleet gateway's side of the fleet: robots learned, trees merged, requests forwarded and fanned out.

Who calls what, on which thread:

- Zenoh's callback threads: :meth:`Aggregator._on_alive` (liveliness tokens ``sovd/*/alive``, with
  history: the robots there before the fleet gateway started are announced too),
  :meth:`_on_fault` (``sovd/*/events/faults``), :meth:`_on_tree` (``sovd/*/events/tree``) and the
  replies of every query.  None does I/O beyond handing a message to the events channel.
- The refresher thread (:meth:`_refresh`, every ``TICK`` s): reads the tree of each robot that
  came, announced a change, or was last read ``fleet_tree_refresh`` s ago (at most
  ``TREE_READS`` at once), pings a robot that was silent ``PING_EVERY`` s (its latency), forgets the
  robots away past ``fleet_forget_after``, and merges the trees again (``merge.py``) when one changed,
  at most every ``MERGE_EVERY`` s.
- The IPC threads (``server.py``) call :meth:`listing`, :meth:`entity`, :meth:`forward`,
  :meth:`fanout`, :meth:`events` and :meth:`robot_status` for the HTTP workers, each within the
  caller's deadline.

Fan-out (medkit's ``fan_out_get``): every robot asked is bounded by ``fleet_timeout`` (and by the
caller's deadline); the answer is whatever arrived by then, with ``x-medkit.partial`` and
``failed_peers`` naming the robots that did not answer in time or answered an error.  All connected
robots are asked with one wildcard query (``sovd/*/read/<family>``), a few targets each with its own.
A robot away is not asked (medkit asks only its healthy peers).
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

import orjson

from ipc import fleet as wire

from . import merge
from .gather import Gather, NotAnswered
from .robots import FaultEvents, Robot, Robots, attributed
from .stats import LinkStats

log = logging.getLogger("sovd.fleet.aggregator")

TICK = 0.1
TREE_READS = 32           # tree reads in flight at once
TREE_RETRY = 5.0          # seconds before a failed tree read is tried again
MERGE_EVERY = 0.25        # seconds: trees that change faster are merged at this pace
PING_EVERY = 15.0         # seconds of silence before a robot is pinged (its latency in /health)
TREE_TIMEOUT_FACTOR = 2.5  # a tree read (four listings) gets this many fleet_timeouts
WILDCARD_FROM = 3         # targets from which one wildcard query asks everybody


class Aggregator:
    def __init__(self, cfg: Any, stats: LinkStats, send_event):
        self.cfg = cfg
        self.stats = stats
        self.send_event = send_event          # the events channel's send (channel.py)
        self.robots = Robots(cfg.fleet_max_robots, cfg.fleet_forget_after)
        self.faults = FaultEvents()
        self.tree = merge.merge([], 0)
        self._generation = 0
        self._dirty = False
        self._merged_at = 0.0
        self._reads = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._session = None
        self._declared: list[Any] = []
        self._thread = threading.Thread(target=self._refresh, name="fleet-refresh", daemon=True)
        self.auth = {"Authorization": f"Bearer {cfg.api_token}"}   # the fleet gateway's own reads
        stats.per_robot = self.robots.per_robot

    # ---- lifecycle ----------------------------------------------------------------------------
    def attach(self, session) -> None:
        self._session = session
        self._declared = [
            session.liveliness().declare_subscriber(wire.ALIVE_ALL, self._on_alive, history=True),
            session.declare_subscriber(wire.FAULT_EVENTS_ALL, self._on_fault),
            session.declare_subscriber(wire.TREE_EVENTS_ALL, self._on_tree),
        ]
        self._thread.start()
        log.info("fleet: aggregating (fleet_timeout %g s, at most %d robots)", self.cfg.fleet_timeout,
                 self.cfg.fleet_max_robots)

    def close(self) -> None:
        self._stop.set()
        for entity in self._declared:
            try:
                entity.undeclare()
            except Exception:
                pass
        if self._thread.is_alive():
            self._thread.join(2.0)

    # ---- Zenoh callbacks ----------------------------------------------------------------------
    def _on_alive(self, sample) -> None:
        import zenoh

        parsed = wire.parse_key(str(sample.key_expr))
        if parsed is None or parsed[1] != "alive" or parsed[2]:
            return
        name = parsed[0]
        if sample.kind == zenoh.SampleKind.PUT:
            robot = self.robots.came(name)
            if robot is None:
                log.warning("fleet: robot %r refused: fleet_max_robots (%d) robots kept", name,
                            self.cfg.fleet_max_robots)
                self.stats.set("robots_refused", self.robots.refused)
                return
            log.info("fleet: robot %r connected", name)
            self._catch_up(robot)
        else:
            if self.robots.went(name) is not None:
                log.info("fleet: robot %r disconnected", name)
                self._changed()
        self._count_robots()

    def _on_tree(self, sample) -> None:
        parsed = wire.parse_key(str(sample.key_expr))
        robot = self.robots.get(parsed[0]) if parsed else None
        if robot is not None:
            robot.tree_changes += 1
            robot.tree_due = 0.0

    def _on_fault(self, sample) -> None:
        parsed = wire.parse_key(str(sample.key_expr))
        robot = self.robots.get(parsed[0]) if parsed else None
        if robot is None:
            return
        try:
            event = orjson.loads(sample.payload.to_bytes())
        except orjson.JSONDecodeError:
            return
        if not isinstance(event, dict) or isinstance(event.get("id"), bool) or not isinstance(event.get("id"), int):
            return
        with self.robots.lock:
            last, gap = robot.last_event, False
            if last is not None and event["id"] <= last:
                self.stats.add("events_duplicates")
                return
            if last is not None and event["id"] > last + 1:
                gap = True           # events were missed: the catch-up brings them, this one with them
            else:
                robot.last_event = event["id"]
        if gap:
            self._catch_up(robot)
        else:
            self._take(robot, event)

    def _take(self, robot: Robot, event: dict[str, Any]) -> None:
        from ipc import events as ipc_events
        from ipc import protocol

        taken = self.faults.take(robot.name, event)
        robot.events += 1
        self.stats.add("events_received")
        self.stats.set("events_kept", len(self.faults.kept))
        self.send_event([ipc_events.FAULT_KEY, protocol.pack(taken)])

    def _catch_up(self, robot: Robot) -> None:
        """Ask the robot for the fault events after the last one taken (its store keeps them)."""
        with self.robots.lock:
            if robot.catching_up:
                return
            robot.catching_up = True
            after = robot.last_event if robot.last_event is not None else -1
        payload = wire.request("GET", wire.API + "/faults", headers=self.auth,
                               budget_ms=int(self.cfg.fleet_timeout * 1000), after=after)

        def answered(status: int, body: bytes) -> None:
            fresh: list[dict[str, Any]] = []
            try:
                data = orjson.loads(body) if status == 200 else {}
                next_id = data.get("next_id")
                with self.robots.lock:
                    if isinstance(next_id, int) and not isinstance(next_id, bool):
                        if after < 0:   # first sight: its events from now on
                            robot.last_event = max(robot.last_event or 0, next_id - 1)
                        elif next_id - 1 < (robot.last_event or 0):   # its fault store began again
                            robot.last_event = next_id - 1
                    last = robot.last_event or 0
                    for event in sorted((e for e in data.get("events") or []
                                         if isinstance(e, dict) and isinstance(e.get("id"), int)),
                                        key=lambda e: e["id"]):
                        if event["id"] > last:     # each id once, however often it is listed
                            fresh.append(event)
                            last = event["id"]
                        else:
                            self.stats.add("events_duplicates")
                    robot.last_event = last
            except (orjson.JSONDecodeError, AttributeError, TypeError):
                log.info("fleet: robot %r answered its events malformed", robot.name)
            finally:
                robot.catching_up = False
            for event in fresh:
                self._take(robot, event)

        self._ask_async(robot, "events", payload, self.cfg.fleet_timeout, answered)

    # ---- queries ------------------------------------------------------------------------------
    def _ask_async(self, robot: Robot, family: str, payload: bytes, timeout: float, answered) -> None:
        """One query to one robot; ``answered(status, body)`` runs when it ends (status 0: no answer)."""
        def settle(gather: Gather) -> None:
            try:
                answered(*self._settle(robot, gather))
            except Exception:
                log.exception("fleet: handling robot %r's %s answer failed", robot.name, family)

        if self._session is None:
            return
        robot.queries += 1
        self.stats.add("queries_sent")
        Gather({robot.name}, on_done=settle).launch(self._session, wire.query_key(robot.name, family), payload,
                                                     timeout)

    def _settle(self, robot: Robot, gather: Gather) -> tuple[int, bytes]:
        got = gather.replies.get(robot.name)
        status, body = 0, b""
        if got is not None:
            robot.answered(got[0])
            try:
                status, _, body = wire.read_reply(got[1])
            except wire.WireError:
                status = 0
        if status == 0 or status >= 400:
            robot.failures += 1
            self.stats.add("query_failures")
        return status, body

    def forward(self, robot_name: str, method: str, path: str, query: str, headers: dict[str, str],
                body: bytes, timeout: float) -> tuple[int, dict[str, str], bytes]:
        """One request to the robot that owns its entity, answered as the robot answered it."""
        robot = self.robots.get(robot_name)
        if robot is None or not robot.online:
            raise NotAnswered(robot_name, "offline", 0.0)
        timeout = min(timeout, self.cfg.fleet_timeout)
        write = wire.is_write(method)
        payload = wire.request(method, path, query, headers, body, int(timeout * 1000))
        self.stats.add("forwards")
        got = self._ask(robot, wire.query_key(robot_name, wire.family_of(path), write), payload, timeout)
        if got is None:
            raise NotAnswered(robot_name, "timeout", timeout)
        return got

    def _ask(self, robot: Robot, selector: str, payload: bytes, timeout: float):
        gather = Gather({robot.name})
        robot.queries += 1
        self.stats.add("queries_sent")
        gather.launch(self._session, selector, payload, timeout)
        gather.wait(timeout + 0.05)
        got = gather.replies.get(robot.name)
        if got is not None:
            robot.answered(got[0])
            try:
                return wire.read_reply(got[1])
            except wire.WireError as exc:
                log.info("fleet: robot %r answered a malformed reply: %s", robot.name, exc)
        robot.failures += 1
        self.stats.add("query_failures")
        return None

    def fanout(self, path: str, query: str, headers: dict[str, str], targets: list[str] | None,
               timeout: float, entity_id: str | None = None) -> bytes:
        """medkit's fan-out of a collection GET; the merged body with ``partial``/``failed_peers``."""
        timeout = min(timeout, self.cfg.fleet_timeout)
        online = {r.name: r for r in self.robots.online()}
        asked = set(online) if targets is None else {t for t in targets if t in online}
        family = wire.family_of(path)
        payload = wire.request("GET", path, query, headers, b"", int(timeout * 1000))
        self.stats.add("fanouts")
        gather = Gather(asked)
        if asked:
            if targets is None and len(asked) >= WILDCARD_FROM:
                gather.launch(self._session, wire.query_key("*", family), payload, timeout)
            else:
                for name in sorted(asked):
                    gather.launch(self._session, wire.query_key(name, family), payload, timeout)
            gather.wait(timeout + 0.05)
        items: list[Any] = []
        base: dict[str, Any] | None = None
        failed = []
        tree = self.tree
        for name in sorted(asked, key=lambda n: online[n].order):
            robot = online[name]
            robot.queries += 1
            got = gather.replies.get(name)
            answer = self._items(got) if got is not None else None
            if answer is None:
                robot.failures += 1
                failed.append(name)
                continue
            robot.answered(got[0])
            got_items, ext = answer
            base = base if base is not None else ext
            items.extend(_renamed(attributed(i, name), tree, name) for i in got_items if isinstance(i, dict))
        self.stats.add("queries_sent", len(asked))
        self.stats.add("query_failures", len(failed))
        ext = dict(base or {})
        if entity_id is not None:
            ext["entity_id"] = entity_id
        for key in ("count", "total_count"):
            if key in ext or (key == "count" and entity_id is None):
                ext[key] = len(items)
        if path == wire.API + "/faults":
            ext.setdefault("muted_count", 0)
            ext.setdefault("cluster_count", 0)
        if failed:
            ext["partial"] = True
            ext["failed_peers"] = failed
        return orjson.dumps({"items": items, "x-medkit": ext})

    @staticmethod
    def _items(got: tuple[float, bytes]) -> tuple[list[Any], dict[str, Any]] | None:
        try:
            status, _, body = wire.read_reply(got[1])
            if not 200 <= status < 300:
                return None
            data = orjson.loads(body)
        except (wire.WireError, orjson.JSONDecodeError):
            return None
        if not isinstance(data, dict):
            return None
        items = data.get("items") if isinstance(data.get("items"), list) else []
        ext = data.get("x-medkit") if isinstance(data.get("x-medkit"), dict) else {}
        return items, ext

    # ---- what the HTTP workers read -----------------------------------------------------------
    def listing(self, collection: str) -> bytes:
        return self.tree.listing(collection)

    def entity(self, collection: str, entity_id: str) -> dict[str, Any]:
        tree = self.tree
        found = tree.entity(collection, entity_id)
        if found is None:
            return {"found": False, "elsewhere": tree.elsewhere(collection, entity_id)}
        route = found["route"]
        online = route is not None and (robot := self.robots.get(route[0])) is not None and robot.online
        return {"found": True, "item": found["item"], "route": list(route) if route else None,
                "online": online, "contributors": found["contributors"], "hosts": found.get("hosts")}

    def events(self, after: int) -> list[dict[str, Any]]:
        return self.faults.after(after)

    def robot_status(self) -> dict[str, Any]:
        robots = sorted(self.robots.snapshot(), key=lambda r: r.name)
        return {"peers": [r.status() for r in robots], "warnings": self.tree.warnings,
                "generation": self.tree.generation}

    # ---- the refresher ------------------------------------------------------------------------
    def _refresh(self) -> None:
        while not self._stop.wait(TICK):
            try:
                self._refresh_once()
            except Exception:  # one bad tree must not stop the refresher
                log.exception("fleet: the refresh failed")

    def _refresh_once(self) -> None:
        now = time.monotonic()
        for name in self.robots.forget_old():
            log.info("fleet: robot %r forgotten (away for fleet_forget_after)", name)
            self._changed()
        for robot in self.robots.online():
            if not robot.tree_reading and robot.tree_due <= now and self._reads < TREE_READS:
                self._read_tree(robot)
            elif robot.ping_due <= now and time.time() - robot.last_seen >= PING_EVERY:
                robot.ping_due = now + PING_EVERY
                self._ask_async(robot, "ping", wire.request("GET", wire.API + "/", headers=self.auth,
                                                            budget_ms=int(self.cfg.fleet_timeout * 1000)),
                                self.cfg.fleet_timeout, lambda status, body: None)
        self._count_robots()
        if self._dirty and now - self._merged_at >= MERGE_EVERY:
            self._merge()

    def _read_tree(self, robot: Robot) -> None:
        robot.tree_reading = True
        changes = robot.tree_changes
        with self._lock:
            self._reads += 1
        timeout = self.cfg.fleet_timeout * TREE_TIMEOUT_FACTOR
        payload = wire.request("GET", wire.API + "/", headers=self.auth, budget_ms=int(timeout * 1000))


        def answered(status: int, body: bytes) -> None:
            try:
                tree = orjson.loads(body) if status == 200 else None
                problem = merge.tree_problem(tree) if status == 200 else f"status {status or 'none'}"
                if problem is None:
                    robot.tree, robot.tree_bytes = tree, len(body)
                    # a change announced while this read was under way: read once more
                    robot.tree_due = 0.0 if robot.tree_changes != changes else \
                        time.monotonic() + self.cfg.fleet_tree_refresh
                    self.stats.add("tree_reads")
                    self._changed()
                else:
                    robot.tree_due = time.monotonic() + TREE_RETRY
                    log.info("fleet: robot %r's tree not taken: %s", robot.name, problem)
            except orjson.JSONDecodeError:
                robot.tree_due = time.monotonic() + TREE_RETRY
            finally:
                robot.tree_reading = False
                with self._lock:
                    self._reads -= 1

        self._ask_async(robot, "tree", payload, timeout, answered)

    def _changed(self) -> None:
        self._dirty = True

    def _merge(self) -> None:
        self._dirty = False
        self._merged_at = time.monotonic()
        trees = [merge.RobotTree(r.name, r.order, r.online, r.tree)
                 for r in self.robots.snapshot() if r.tree is not None]
        self._generation += 1
        merged = merge.merge(trees, self._generation)
        self.tree = merged
        self.stats.add("tree_merges")
        self.stats.set("tree_entities", merged.size)
        self.stats.set("tree_bytes", sum(r.tree_bytes for r in self.robots.snapshot()))

    def _count_robots(self) -> None:
        robots = self.robots.snapshot()
        self.stats.set("robots_known", len(robots))
        self.stats.set("robots_online", sum(r.online for r in robots))
        self.stats.set("robots_refused", self.robots.refused)


def _renamed(item: dict[str, Any], tree: merge.Merged, robot: str) -> dict[str, Any]:
    """medkit's re-attribution: an item's ``member_ids`` named as the fleet names the robot's apps."""
    ext = item.get("x-medkit")
    members = ext.get("member_ids") if isinstance(ext, dict) else None
    if isinstance(members, list) and tree.renamed.get(robot):
        ext["member_ids"] = [tree.member_id(robot, m) if isinstance(m, str) else m for m in members]
    return item
