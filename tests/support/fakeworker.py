"""A stand-in ROS worker for unit tests of the HTTP side: a real ZeroMQ ROUTER socket.

It binds ``ipc://<runtime_dir>/rosworker.sock`` and ``rosworker-ctl.sock`` like the real one and answers
the commands of ``ipc/PROTOCOL.md`` from canned data, in a thread:

    fw = FakeWorker().start()
    fw.set_graph([node("/powertrain/engine/temp_sensor", publishes=[("/powertrain/engine/temperature",
                                                                      "sensor_msgs/msg/Temperature")])])
    fw.samples["/powertrain/engine/temperature"] = data_sample(..., {"temperature": 93.5})
    fw.silent.add("sample")          # never answer samples (timeouts)
    fw.errors["publish"] = IpcError("invalid-data", "...")
    fw.requests                      # [(cmd, args, deadline_ms), ...] as received
    fw.envelopes                     # the whole request maps, as received
    fw.stop()

A reply can be a dict, an :class:`IpcError`, or a callable ``args -> dict``.
"""

from __future__ import annotations

import heapq
import itertools
import shutil
import tempfile
import threading
import time
from typing import Any

import orjson
import zmq

from ipc import protocol
from ipc.errors import IpcError

DEFAULT_TOPICS = (("/rosout", "rcl_interfaces/msg/Log"),)
DEFAULT_SUBSCRIPTIONS = (("/parameter_events", "rcl_interfaces/msg/ParameterEvent"),)
STATS = {
    "data_provider": {"pool_size": 1, "pool_cap": 256, "pool_hits": 5, "pool_misses": 2,
                      "evictions_total": 0, "type_change_events": 0, "graph_events_received": 3,
                      "concurrent_cold_waits": 0, "cold_wait_cap": 4, "unsupported_type_count": 0,
                      "undecodable_messages": 0, "pool_bytes": 2048, "pool_bytes_cap": 268435456},
    "executor": {"worker_alive": True, "degraded": False, "queue_depth": 0, "queue_max_depth_observed": 2,
                 "queue_dropped": 0, "tasks_completed": 9, "tasks_failed": 0, "last_task_latency_us": 120,
                 "max_task_latency_us": 900, "current_task_age_ms": 0, "watchdog_trips": 0,
                 "graph_events_received": 3, "loop_errors": 0, "loop_wakeups": 0},
    "details": {"evictions": {"graph": 1, "type_change": 0, "lru": 2, "idle": 0, "qos_rebuild": 0,
                              "manual": 0, "shutdown": 0, "bytes": 0}},
}


def node(fqn: str, publishes=(), subscribes=(), defaults: bool = True) -> dict[str, Any]:
    """One entry of the ``graph`` answer's ``nodes``; adds /rosout and /parameter_events."""
    namespace, _, name = fqn.rpartition("/")
    pubs = [list(p) for p in publishes] + ([list(p) for p in DEFAULT_TOPICS] if defaults else [])
    subs = [list(s) for s in subscribes] + ([list(s) for s in DEFAULT_SUBSCRIPTIONS] if defaults else [])
    return {"name": name, "namespace": namespace or "/", "fqn": fqn,
            "publishes": sorted(pubs), "subscribes": sorted(subs)}


def topics_of(nodes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    table: dict[str, dict[str, Any]] = {}
    for n in nodes:
        for key, count in (("publishes", "publisher_count"), ("subscribes", "subscriber_count")):
            for name, type_ in n[key]:
                t = table.setdefault(name, {"name": name, "types": [type_], "publisher_count": 0,
                                            "subscriber_count": 0})
                t[count] += 1
    return [table[k] for k in sorted(table)]


def data_sample(topic: str, type_: str, data: Any, publishers: int = 1, subscribers: int = 0,
                timestamp: int = 1769955039964403368) -> dict[str, Any]:
    return {"topic": topic, "type": type_, "status": "data", "data_json": orjson.dumps(data),
            "timestamp": timestamp, "publisher_count": publishers, "subscriber_count": subscribers}


def metadata_sample(topic: str, type_: str | None = None, reason: str = "not-in-graph",
                    publishers: int = 0) -> dict[str, Any]:
    return {"topic": topic, "type": type_, "status": "metadata_only", "data_json": b"{}",
            "timestamp": time.time_ns(), "publisher_count": publishers, "subscriber_count": 0,
            "reason": reason}


class FakeWorker:
    def __init__(self, runtime_dir: str | None = None):
        self._own_dir = runtime_dir is None
        self.runtime_dir = runtime_dir or tempfile.mkdtemp(prefix="sovd-fw-")
        self.endpoint = protocol.endpoint(self.runtime_dir)
        self.generation = 1
        self.nodes: list[dict[str, Any]] = []
        self.topics: list[dict[str, Any]] = []
        self.samples: dict[str, Any] = {}
        self.type_infos: dict[str, dict[str, Any]] = {}
        self.stats: dict[str, Any] = {k: dict(v) for k, v in STATS.items()}
        self.errors: dict[str, IpcError] = {}
        self.silent: set[str] = set()
        self.delays: dict[str, float] = {}
        self.requests: list[tuple[str, dict[str, Any], int]] = []
        self.envelopes: list[dict[str, Any]] = []
        self.subscriptions: dict[str, dict[str, Any]] = {}
        self.apps: list[Any] = []  # Flask apps made by make_app(self): closed with the worker
        self.locks: Any = None        # locks: rosworker/locks/'s LockTable, made on the first lock_* command
        self.lock_stats: Any = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._bound = threading.Event()
        self._thread: threading.Thread | None = None

    # ---------------------------------------------------------------- programming

    def set_graph(self, nodes: list[dict[str, Any]], topics: list[dict[str, Any]] | None = None) -> None:
        with self._lock:
            self.nodes = nodes
            self.topics = topics_of(nodes) if topics is None else topics
            self.generation += 1

    def calls(self, cmd: str) -> list[dict[str, Any]]:
        with self._lock:
            return [args for c, args, _ in self.requests if c == cmd]

    def deadlines(self, cmd: str) -> list[int]:
        with self._lock:
            return [d for c, _, d in self.requests if c == cmd]

    # ---------------------------------------------------------------- lifecycle

    def start(self) -> FakeWorker:
        self._thread = threading.Thread(target=self._run, name="fakeworker", daemon=True)
        self._thread.start()
        if not self._bound.wait(5):
            raise RuntimeError("fake worker did not bind")
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)

    def close(self) -> None:
        from app.core import rosclient

        for app in self.apps:
            app.extensions[rosclient.EXTENSION].close()
            if "sovd_audit" in app.extensions:   # the audit trail's writer (app/audit/)
                app.extensions["sovd_audit"].close()
        self.stop()
        if self._own_dir:
            shutil.rmtree(self.runtime_dir, ignore_errors=True)

    def __enter__(self) -> FakeWorker:
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ---------------------------------------------------------------- the loop

    def _run(self) -> None:
        ctx = zmq.Context()
        sockets = []
        for endpoint in (self.endpoint, protocol.control_endpoint(self.endpoint)):
            sock = ctx.socket(zmq.ROUTER)
            sock.setsockopt(zmq.LINGER, 0)
            sock.bind(endpoint)
            sockets.append(sock)
        poller = zmq.Poller()
        for sock in sockets:
            poller.register(sock, zmq.POLLIN)
        self._bound.set()
        pending: list[tuple[float, int, zmq.Socket, bytes, bytes]] = []
        seq = itertools.count()
        try:
            while not self._stop.is_set():
                timeout = 20
                if pending:
                    timeout = max(0, min(timeout, int((pending[0][0] - time.monotonic()) * 1000)))
                for sock, _ in poller.poll(timeout):
                    ident, frame = sock.recv_multipart()
                    reply = self._answer(frame)
                    if reply is not None:
                        due, payload = reply
                        heapq.heappush(pending, (due, next(seq), sock, ident, payload))
                while pending and pending[0][0] <= time.monotonic():
                    _, _, sock, ident, payload = heapq.heappop(pending)
                    sock.send_multipart([ident, payload])
        finally:
            for sock in sockets:
                sock.close(linger=0)
            ctx.term()

    def _answer(self, frame: bytes) -> tuple[float, bytes] | None:
        msg = protocol.unpack(frame)
        cmd, args, rid = msg.get("cmd"), msg.get("args") or {}, msg.get("id")
        with self._lock:
            self.requests.append((cmd, args, msg.get("deadline_ms")))
            self.envelopes.append(msg)
            if cmd in self.silent:
                return None
            try:
                if cmd in self.errors:
                    raise self.errors[cmd]
                result = self._result(cmd, args)
                if isinstance(result, IpcError):
                    raise result
                reply = {"v": 1, "id": rid, "ok": True, "result": result}
            except IpcError as exc:
                reply = {"v": 1, "id": rid, "ok": False, "error": exc.to_wire()}
            due = time.monotonic() + self.delays.get(cmd, 0.0)
        return due, protocol.pack(reply)

    def _result(self, cmd: str, args: dict[str, Any]) -> Any:
        if cmd == "ping":
            return {"pid": 1, "uptime_s": 1.0, "version": "0", "protocol": 1, "node": "fake_sub",
                    "started_at": 0}
        if cmd == "stats":
            return {**self.stats, "pid": 1}
        if cmd == "graph":
            if args.get("since") == self.generation:
                return {"generation": self.generation, "unchanged": True}
            return {"generation": self.generation, "unchanged": False, "nodes": self.nodes,
                    "topics": self.topics}
        if cmd == "sample":
            reply = self.samples.get(args.get("topic"))
            if reply is None:
                return metadata_sample(args.get("topic"))
            return reply(args) if callable(reply) else reply
        if cmd == "type_info":
            info = self.type_infos.get(args.get("type"))
            if info is None:
                return IpcError("type-not-installed", f"message type {args.get('type')} is not installed",
                                {"type": args.get("type")})
            return {"type": args["type"], **info}
        if cmd.startswith("sub_"):
            return self._subscription(cmd, args)
        if cmd == "publish":
            return {"topic": args.get("topic"), "type": args.get("type"), "status": "published",
                    "subscriber_count": 1, "unmatched_subscriber_count": 0}
        # configurations: the param_* commands answer what a test puts in ``fw.replies`` (a dict or args -> dict)
        reply = getattr(self, "replies", {}).get(cmd)
        if reply is not None:
            return reply(args) if callable(reply) else reply
        # logs (issue 22): one line of each node asked, and a configuration echoed (rosworker/logs/book.py)
        if cmd == "logs":
            return {"rows": [[n, 1700000000, 5, 30, fqn.lstrip("/").replace("/", "."), "a line", "f.py", "fn", 3]
                             for n, fqn in enumerate(args.get("nodes") or [], 1)]}
        if cmd in ("log_config_get", "log_config_set"):
            return {"severity_filter": args.get("severity_filter", "debug"), "max_entries": args.get("max_entries", 100)}
        if cmd.startswith("trig_"):  # triggers
            return self._trigger(cmd, args)
        if cmd == "lifecycle_state":  # GET .../status: a plain node (a test may put another answer in replies)
            return {"managed": False, "state": None}
        if cmd.startswith("lock_"):  # locks: the ROS worker's own table (rosworker/locks/: no rclpy in it)
            return self._lock_command(cmd, args)
        return IpcError("unknown-command", f"unknown command {cmd!r}")

    def _lock_command(self, cmd: str, args: dict[str, Any]) -> Any:
        if self.locks is None:
            from types import SimpleNamespace

            from ipc import counters
            from rosworker.locks import LockTable

            stats = SimpleNamespace(**{c.name: 0 for c in counters.section("locks", counters.ROS)})
            self.locks = LockTable(self.runtime_dir, stats, max_locks=100, max_expiration=3600,
                                   cleanup_interval=3600, call_later=lambda *_: None, restore=False)
            self.lock_stats = stats
        answer: list[Any] = []
        task = SimpleTask(args, answer.append)
        try:
            self.locks.commands[cmd](task)
        except IpcError as exc:
            return exc
        return answer[0]


    def _subscription(self, cmd: str, args: dict[str, Any]) -> Any:
        """The ``sub_*`` commands over a plain dict (the real registry is rosworker/subscriptions/registry.py)."""
        owner = (args.get("collection"), args.get("entity_id"))
        if cmd == "sub_create":
            sub_id = f"sub_{len(self.subscriptions) + 1:016x}"
            now = time.time_ns()
            sub = {k: args[k] for k in ("collection", "entity_id", "resource", "topic", "bytes", "interval",
                                        "duration")}
            sub.update(id=sub_id, expires_at_ns=now + args["duration"] * 10**9, created_at_ns=now,
                       key=f"d|{args['interval']}|{args['bytes']}|{args['topic']}|".encode())
            self.subscriptions[sub_id] = sub
            return sub
        if cmd == "sub_list":
            return {"items": [s for s in self.subscriptions.values()
                              if (s["collection"], s["entity_id"]) == owner]}
        sub = self.subscriptions.get(args.get("id"))
        if sub is None or (sub["collection"], sub["entity_id"]) != owner:
            return IpcError("no-such-subscription", "Subscription not found", {"subscription_id": args.get("id")})
        if cmd == "sub_get":
            return sub
        if cmd == "sub_update":
            for key in ("interval", "duration"):
                if args.get(key) is not None:
                    sub[key] = args[key]
            return sub
        if cmd == "sub_delete":
            del self.subscriptions[sub["id"]]
            return {}
        return IpcError("unknown-command", f"unknown command {cmd!r}")

    # Triggers: the ``trig_*`` commands over a plain dict (the real registry is rosworker/triggers/registry.py).
    def _trigger(self, cmd: str, args: dict[str, Any]) -> Any:
        triggers = self.__dict__.setdefault("triggers", {})
        owner = (args.get("collection"), args.get("entity_id"))
        if cmd == "trig_create":
            trig = {k: args[k] for k in ("collection", "entity_id", "resource", "source", "target", "bytes", "path",
                                         "condition", "multishot", "persistent", "lifetime", "client")}
            trig.update(id=f"trig_{len(triggers) + 1:016x}", status="active", created_at_ns=time.time_ns(),
                        expires_at_ns=None, replayable=False)
            triggers[trig["id"]] = trig
            return trig
        if cmd == "trig_list":
            return {"items": [t for t in triggers.values() if (t["collection"], t["entity_id"]) == owner]}
        trig = triggers.get(args.get("id"))
        if trig is None or (trig["collection"], trig["entity_id"]) != owner:
            return IpcError("no-such-trigger", "Trigger not found", {"trigger_id": args.get("id")})
        if cmd in ("trig_get", "trig_open"):
            return trig
        if cmd == "trig_update":
            trig["lifetime"] = args["lifetime"]
            return trig
        if cmd == "trig_delete":
            del triggers[trig["id"]]
            return {}
        return IpcError("unknown-command", f"unknown command {cmd!r}")


class SimpleTask:
    """What a ROS-worker command handler gets: its ``args`` and ``reply``."""

    def __init__(self, args: dict[str, Any], reply: Any):
        self.args = args
        self.reply = reply


def error_of(r, status: int, error_code: str, vendor_code: str | None = None) -> dict:
    """The contract's error body of a test client's answer ``r``, checked: its status, its codes, and a message."""
    assert r.status_code == status, r.data
    doc = r.get_json()
    assert doc["error_code"] == error_code, doc
    assert doc.get("vendor_code") == vendor_code, doc
    assert isinstance(doc["message"], str) and doc["message"]
    return doc


def make_app(worker: FakeWorker | None = None, runtime_dir: str | None = None, **overrides: Any):
    """The Flask app (``app.wsgi.create_app``) wired to ``worker``'s socket.

    Defaults for tests: hostname ``test-robot``, graph asked on every request.
    """
    from app.wsgi import create_app

    directory = runtime_dir or worker.runtime_dir
    # The audit trail and the revoked tokens (access.db) go to the test's own directory, not the user's.
    config = {"runtime_dir": directory, "state_dir": directory, "SOVD_HOSTNAME": "test-robot",
              "SOVD_GRAPH_REFRESH_S": 0.0, **overrides}
    app = create_app(config)
    if worker is not None:
        worker.apps.append(app)
    return app


ROBOT = [
    node("/powertrain/engine/temp_sensor", [("/powertrain/engine/temperature", "sensor_msgs/msg/Temperature")]),
    node("/chassis/brakes/pressure_sensor", [("/chassis/brakes/pressure", "std_msgs/msg/Float32")]),
    node("/body/lights/controller", [("/body/lights/state", "std_msgs/msg/Bool")],
         [("/body/lights/cmd", "std_msgs/msg/Bool")]),
]
