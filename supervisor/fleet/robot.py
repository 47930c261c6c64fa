"""A robot's side of the fleet: its liveliness token, its queryables, its events.

Who calls what, on which thread:

- :meth:`RobotLink.attach` runs once the Zenoh session is open (``session.Opener``'s thread): it
  declares ``sovd/<fleet_id>/alive`` (the fleet learns the robot from it), the queryables
  ``sovd/<fleet_id>/read/**`` and ``.../write/**`` and the event publishers, then starts the two
  watcher threads below.
- :meth:`RobotLink._on_query` runs on a Zenoh thread for each query and does no I/O: it checks the
  envelope (``wire.read_request``), that the key's family is the path's, that a write came on a
  write key and is allowed (``fleet_allow_writes``), refuses streams, and hands the query to the
  pool (``QUERY_THREADS`` threads; past ``MAX_PENDING`` queries in hand it answers 503 at once).
- A pool thread answers it: a SOVD request is made to the robot's own gateway over the loopback
  (``loopback.py``) with the caller's headers, so the gateway's own checks decide, and its answer
  goes back as it is.  The link's own reads (``tree``, ``events``, ``ping``) are answered only
  after the gateway accepted the caller's identity (a ``GET /api/v1/`` with its headers).
- The events thread reads the ROS worker's events channel (``ipc/events.py``: fault events ``f|``,
  trigger events ``t|g|``, one frame per change for every trigger it fired) and publishes each event on ``sovd/<fleet_id>/events/faults`` or
  ``.../events/triggers/<id>`` (JSON).  Fault events carry the ids of the robot's fault store; a gap
  (events missed while the ROS worker restarted) is filled from the store (``fault_events``).
- The tree thread asks the ROS worker for its graph's generation every ``TREE_POLL`` seconds (the
  cheap ``graph since`` round trip) and announces a change on ``sovd/<fleet_id>/events/tree``, so
  the fleet gateway reads the robot's tree again only when it changed.
"""

from __future__ import annotations

import logging
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import orjson

from common.process import package_version
from ipc import events as ipc_events
from ipc import fleet as wire
from ipc import protocol
from ipc.client import RosWorkerClient
from ipc.errors import IpcError

from .loopback import Loopback, TooLarge
from .stats import LinkStats

log = logging.getLogger("sovd.fleet.robot")

QUERY_THREADS = 8         # queries answered at once (each waits on the robot's own gateway)
MAX_PENDING = 256         # queries in hand (answering or waiting for a thread); past it: 503 at once
TREE_POLL = 2.0           # seconds between two looks at the ROS graph's generation
EVENTS_POLL_MS = 1000    # the events thread's wait when nothing comes (its stop is seen within it)
IPC_TIMEOUT = 2.0
TREE_COLLECTIONS = ("areas", "components", "apps", "functions")
STREAM_PATHS = ("/api/v1/faults/stream",)


def _is_stream(path: str, family: str) -> bool:
    return path in STREAM_PATHS or (family in ("triggers", "subscriptions") and path.endswith("/events"))


class RobotLink:
    def __init__(self, cfg: Any, stats: LinkStats):
        self.cfg = cfg
        self.fleet_id = cfg.fleet_id
        self.stats = stats
        self.loopback = Loopback(cfg.bind)
        self.ros = RosWorkerClient.for_runtime_dir(cfg.runtime_dir)
        self.pool = ThreadPoolExecutor(max_workers=QUERY_THREADS, thread_name_prefix="fleet-query")
        self._pending = 0
        self._pending_lock = threading.Lock()
        self._stop = threading.Event()
        self._declared: list[Any] = []
        self._threads: list[threading.Thread] = []
        self._fault_pub = None
        self._session = None
        self.last_fault_id = 0

    # ---- lifecycle ----------------------------------------------------------------------------
    def attach(self, session) -> None:
        self._session = session
        read_key, write_key = wire.queryable_keys(self.fleet_id)
        self._declared = [
            session.liveliness().declare_token(wire.alive_key(self.fleet_id)),
            session.declare_queryable(read_key, self._on_query),
            session.declare_queryable(write_key, self._on_query),
        ]
        self._fault_pub = session.declare_publisher(wire.event_key(self.fleet_id, "faults"))
        for name, target in (("fleet-events", self._relay_events), ("fleet-tree", self._watch_tree)):
            thread = threading.Thread(target=target, name=name, daemon=True)
            thread.start()
            self._threads.append(thread)
        log.info("fleet: robot %r joined (queryables %s, %s)", self.fleet_id, read_key, write_key)

    def close(self) -> None:
        self._stop.set()
        for entity in (*self._declared, self._fault_pub):
            if entity is not None:
                try:
                    entity.undeclare()
                except Exception:
                    pass
        self._declared = []
        self.pool.shutdown(wait=False, cancel_futures=True)
        for thread in self._threads:
            thread.join(2.0)
        self.ros.close()

    # ---- queries ------------------------------------------------------------------------------
    def _on_query(self, query) -> None:
        """On a Zenoh thread: check, then hand over to the pool (never any I/O here)."""
        started = time.monotonic()
        kind, family = wire.query_parts(str(query.key_expr))
        reply_key = wire.query_key(self.fleet_id, family or "other", kind == "write")
        try:
            if kind not in ("read", "write") or family not in wire.FAMILIES:
                raise _Refused(400, "invalid-request", f"not a fleet query key: {str(query.key_expr)[:200]}")
            payload = query.payload
            req = wire.read_request(payload.to_bytes() if payload is not None else b"")
            self._check(req, kind, family)
        except wire.WireError as exc:
            self._refuse(query, reply_key, _Refused(400, "invalid-request", f"malformed fleet request: {exc}"))
            return
        except _Refused as refused:
            self._refuse(query, reply_key, refused)
            return
        with self._pending_lock:
            busy = self._pending >= MAX_PENDING
            if not busy:
                self._pending += 1
        if busy:
            self.stats.add("queries_busy")
            query.reply(reply_key, wire.reply(503, wire.error_body(
                503, "service-unavailable", f"robot {self.fleet_id!r} has {MAX_PENDING} fleet queries in hand",
                fleet_id=self.fleet_id), {"Content-Type": "application/json", "Retry-After": "1"}))
            return
        try:
            self.pool.submit(self._answer, query, reply_key, req, family, started)
        except RuntimeError:  # shutting down
            with self._pending_lock:
                self._pending -= 1

    def _check(self, req: dict[str, Any], kind: str, family: str) -> None:
        path, method = req["p"], req["m"]
        if family not in wire.LINK_FAMILIES and wire.family_of(path) != family:
            raise _Refused(400, "invalid-request", f"the key's family {family!r} is not the path's "
                           f"({wire.family_of(path)!r})")
        if wire.is_write(method) != (kind == "write"):
            raise _Refused(400, "invalid-request", f"{method} does not go on a {kind} key")
        if kind == "write" and not self.cfg.fleet_allow_writes:
            raise _Refused(403, "forbidden", f"Writes through the fleet are disabled on robot {self.fleet_id!r}",
                           details="start its gateway with --fleet-allow-writes to allow them")
        if _is_stream(path, family):
            raise _Refused(400, "invalid-request", "streams are not carried through the fleet: read the "
                           "fleet gateway's /api/v1/faults/stream, or the robot's own gateway")

    def _refuse(self, query, key: str, refused: _Refused) -> None:
        self.stats.add("queries_refused")
        query.reply(key, wire.error_reply(refused.status, refused.code, refused.message,
                                          fleet_id=self.fleet_id, **refused.params))

    def _answer(self, query, key: str, req: dict[str, Any], family: str, started: float) -> None:
        try:
            budget = req["t"] / 1000.0 - (time.monotonic() - started)
            if budget <= 0:
                return  # the caller has given up; no answer is better than a late one
            if family == "tree":
                frame = self._tree(req, budget)
            elif family in ("events", "ping"):
                frame = self._identified(req, budget, self._events if family == "events" else self._ping)
            else:
                status, headers, body = self.loopback.request(req["m"], req["p"], req["q"], req["h"],
                                                              req["b"], budget)
                frame = wire.reply(status, body, headers)
                if status in (401, 403):
                    self.stats.add("queries_refused")
            self.stats.add("queries_answered")
            query.reply(key, frame)
        except TooLarge as exc:
            self.stats.add("queries_answered")
            query.reply(key, wire.error_reply(502, "vendor-error", f"the answer ({exc.args[0]} bytes) is larger "
                                              f"than the fleet carries ({wire.MAX_BODY} bytes)",
                                              fleet_id=self.fleet_id))
        except OSError as exc:
            self.stats.add("loopback_errors")
            log.info("fleet: the gateway did not answer %s %s: %s", req["m"], req["p"], exc)
            query.reply(key, wire.error_reply(504, "not-responding", f"robot {self.fleet_id!r}: its gateway did "
                                              "not answer in time", fleet_id=self.fleet_id))
        except Exception:
            log.exception("fleet: answering %s %s failed", req.get("m"), req.get("p"))
            query.reply(key, wire.error_reply(500, "internal-error", "the fleet link failed to answer (logged)"))
        finally:
            with self._pending_lock:
                self._pending -= 1
            del query  # the query is finalized (its caller told no more replies come) when dropped

    def _tree(self, req: dict[str, Any], budget: float) -> bytes:
        """The four entity listings in one answer (each read with the caller's identity)."""
        deadline = time.monotonic() + budget
        tree: dict[str, Any] = {"fleet_id": self.fleet_id}
        for collection in TREE_COLLECTIONS:
            status, headers, body = self.loopback.request("GET", f"{wire.API}/{collection}", "", req["h"], b"",
                                                          deadline - time.monotonic())
            if status != 200:
                return wire.reply(status, body, headers)
            tree[collection] = orjson.loads(body).get("items") or []
        return wire.reply(200, orjson.dumps(tree), {"Content-Type": "application/json"})

    def _identified(self, req: dict[str, Any], budget: float, answer) -> bytes:
        deadline = time.monotonic() + budget
        status, headers, body = self.loopback.request("GET", wire.API + "/", "", req["h"], b"", budget)
        if status != 200:
            self.stats.add("queries_refused")
            return wire.reply(status, body, headers)
        return answer(req, deadline)

    def _ping(self, req: dict[str, Any], deadline: float) -> bytes:
        return wire.reply(200, orjson.dumps({"fleet_id": self.fleet_id, "version": package_version()}),
                          {"Content-Type": "application/json"})

    def _events(self, req: dict[str, Any], deadline: float) -> bytes:
        """Fault events after ``after`` from the robot's fault store (none for a negative ``after``)."""
        after = req.get("after", -1)
        if isinstance(after, bool) or not isinstance(after, int):
            return wire.error_reply(400, "invalid-request", "after: an event id")
        try:
            answer = self.ros.call("fault_events", {"after": max(0, after)},
                                   timeout=max(0.05, deadline - time.monotonic()))
        except IpcError as exc:
            return wire.error_reply(503, "service-unavailable", f"the fault store did not answer: {exc.message}")
        body = {"events": answer.get("events") or [] if after >= 0 else [], "next_id": answer.get("next_id", 0)}
        return wire.reply(200, orjson.dumps(body), {"Content-Type": "application/json"})

    # ---- events -------------------------------------------------------------------------------
    def _relay_events(self) -> None:
        import zmq

        ctx = zmq.Context()
        sock = ctx.socket(zmq.SUB)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.RCVHWM, ipc_events.HIGH_WATER)
        sock.setsockopt(zmq.MAXMSGSIZE, protocol.MAX_REPLY_FRAME)
        sock.setsockopt(zmq.RECONNECT_IVL, 100)
        sock.setsockopt(zmq.RECONNECT_IVL_MAX, 1000)
        for key in (ipc_events.FAULT_KEY, ipc_events.TRIGGER_GROUP_PREFIX):
            sock.setsockopt(zmq.SUBSCRIBE, key)
        sock.connect(ipc_events.endpoint(self.cfg.runtime_dir))
        try:
            while not self._stop.is_set():
                if not sock.poll(EVENTS_POLL_MS):
                    continue
                while True:
                    try:
                        frames = sock.recv_multipart(zmq.NOBLOCK)
                    except zmq.Again:
                        break
                    try:
                        self._event(frames)
                    except Exception:  # a malformed frame must not end the relay
                        log.exception("fleet: could not relay an event")
        finally:
            sock.close(linger=0)
            ctx.term()

    def _event(self, frames: list[bytes]) -> None:
        if len(frames) < 2:
            return  # a subscription's confirmation
        if frames[0] == ipc_events.FAULT_KEY:
            event = protocol.unpack(frames[1], protocol.MAX_REPLY_FRAME)
            event_id = event.get("id")
            if not isinstance(event_id, int) or event_id <= self.last_fault_id:
                return
            if self.last_fault_id and event_id > self.last_fault_id + 1:
                self._fill_gap(event_id)
            self._publish_fault(event)
        elif frames[0].startswith(ipc_events.TRIGGER_GROUP_PREFIX) and len(frames) >= 3:
            meta = protocol.unpack(frames[1], protocol.MAX_REPLY_FRAME)
            fired = meta.get("fired") if isinstance(meta, dict) else None
            if not isinstance(fired, list):
                return
            try:
                payload = orjson.loads(frames[2]) if frames[2] else None
            except orjson.JSONDecodeError:
                payload = None
            common = {k: meta[k] for k in ("ts", "error") if k in meta}
            for entry in fired:  # each trigger's event, as it would have been on its own
                if not isinstance(entry, list) or len(entry) != 3 or not isinstance(entry[0], str):
                    continue
                trigger_id, seq, last = entry
                body = {"trigger_id": trigger_id, "seq": seq, **common, **({"last": True} if last else {}),
                        "payload": payload}
                self._session.put(wire.event_key(self.fleet_id, "triggers", trigger_id), orjson.dumps(body))
                self.stats.add("events_published")

    def _fill_gap(self, upto: int) -> None:
        try:
            missed = self.ros.call("fault_events", {"after": self.last_fault_id}, timeout=IPC_TIMEOUT)
        except IpcError as exc:
            log.info("fleet: fault events after %d not read from the store: %s", self.last_fault_id, exc.message)
            return
        for event in missed.get("events") or []:
            if isinstance(event, dict) and isinstance(event.get("id"), int) \
                    and self.last_fault_id < event["id"] < upto:
                self._publish_fault(event)

    def _publish_fault(self, event: dict[str, Any]) -> None:
        self.last_fault_id = event["id"]
        body = {"id": event["id"], "event_type": event.get("event_type"), "fault": event.get("fault"),
                "timestamp": event.get("timestamp")}
        self._fault_pub.put(orjson.dumps(body))
        self.stats.add("events_published")

    # ---- the tree -----------------------------------------------------------------------------
    def _watch_tree(self) -> None:
        generation = None
        while not self._stop.wait(TREE_POLL):
            try:
                args = {"since": generation} if generation is not None else {}
                answer = self.ros.call("graph", args, timeout=IPC_TIMEOUT)
            except IpcError:
                continue
            current = answer.get("generation")
            if not isinstance(current, int) or current == generation:
                continue
            # The first answer too: the fleet may have read the tree before this link first looked.
            self._session.put(wire.event_key(self.fleet_id, "tree"), orjson.dumps({"generation": current}))
            self.stats.add("tree_changes")
            generation = current


class _Refused(Exception):
    def __init__(self, status: int, code: str, message: str, **params: Any):
        super().__init__(message)
        self.status, self.code, self.message, self.params = status, code, message, params
