"""SOVD triggers: conditions evaluated on every message of a watched resource, events on firing only.

Every method runs on the ROS thread, except the store's writer (a thread of
its own, like the restart state's).  The ROS worker is the single owner of
the triggers, so that one made through one HTTP worker streams through any
other.

Sources.  What a trigger observes is a *source* kind, one class per
collection of :data:`SOURCES` (``data`` today; ``faults`` and ``logs`` are
one more entry each once they exist).  A source is handed the triggers of
its kind (``attach``/``detach``), polled by the executor while it has any
(:meth:`RosExecutor.add_poller`), and calls :meth:`TriggerRegistry.fire`.

Data triggers, per topic, not per trigger.  A watched topic gets its own
subscription (``KEEP_LAST`` ``TRIGGER_DEPTH``, QoS matched to its
publishers), apart from the pool's depth-1 one, so that every message is
seen, not only the newest.  Each round of the loop takes what arrived, at
most ``TAKES_PER_ROUND`` messages per topic and ``ROUND_BUDGET`` seconds in
all (the rest wait in the subscription's queue for the next round, after
the commands and timers: a busy topic cannot hold the thread; past its
``TRIGGER_DEPTH`` the middleware drops the oldest), converts each
message once to JSON (``rosworker/ros/encode.py``; NaN and ±inf as the strings
"NaN", "Infinity", "-Infinity") and evaluates every trigger of the topic
on it.  A topic nobody watches has no such subscription: zero per-message
work, as before.  A topic that is not in the graph yet (a restored trigger,
a late publisher) is tried again every ``PENDING_RETRY`` s.

Conditions (medkit's): ``OnChange`` fires on the first value and on every
change; ``OnChangeTo`` when the value becomes ``target_value`` (the first
value only checks the target); ``EnterRange``/``LeaveRange`` on the
crossing of the inclusive ``[lower_bound, upper_bound]`` (a previous value
is needed).  Values are compared as IEEE numbers: NaN is in no range, and
two NaN are no change.  A ``path`` (JSON Pointer) picks the value in the
message; a message without it is not evaluated.

Events.  Only firing crosses to the HTTP workers, on the events channel:
``t|e|<id>|`` + msgpack ``{"ts", "seq", "last"?, "error"?}`` + the JSON of
the message.  A one-shot trigger's event is its last (``last``); it is then
``terminated`` and kept ``TERMINATED_KEEP`` s, so a stream opened just
after it fired still gets that event (``trig_open`` hands the newest event
that no stream has been opened for yet).  Deletion and expiry are control
frames ``t|c|<id>|``.

Store.  A trigger's record is made once per change and written as one row
of the ``triggers`` table of the state directory's SQLite store
(``rosworker/core/store.py``, beside the faults) by the store's thread; a
command that changed a trigger is answered once its row is written.  A
restarted ROS worker restores them all; a new gateway only the
``persistent`` ones (the others' rows are deleted).  They are restored before
their topics are discovered (the topic is subscribed once it shows).  A
``triggers.json`` left by an older gateway is imported once (and renamed
``triggers.json.imported``).

Bounds.  What a trigger holds is small: a ``target_value`` of at most
``TARGET_VALUE_MAX`` bytes of JSON, a ``path`` of ``jsonpointer.MAX_LENGTH``
characters (the HTTP side refuses more with a 400 that names the limit); the
records of all triggers together at most ``max_trigger_bytes``, and at most
``max_triggers`` of them: past either the next one is refused
(``triggers-full``) and nothing held is touched.
"""

from __future__ import annotations

import json
import logging
import math
import os
import secrets
import time
from collections.abc import Callable
from typing import Any

import orjson
import zmq

from ipc import events, jsonpointer, protocol
from ipc.errors import IpcError
from ipc.topics import InvalidTopic, normalize_topic

from ..core.executor import RosExecutor, Task, Timer
from ..core.graph import Endpoints
from ..core.stats import Stats
from ..core.store import FaultStore
from ..ros import msgtypes, qos
from ..ros.encode import to_json

log = logging.getLogger("sovd.rosworker.triggers")

CONDITIONS = ("OnChange", "OnChangeTo", "EnterRange", "LeaveRange")
TRIGGER_DEPTH = 256       # messages a watched topic's subscription queues between two rounds
TAKES_PER_ROUND = 256     # messages one topic may take per round of the loop
ROUND_BUDGET = 0.01       # seconds of evaluation per round of the loop, all topics together
PENDING_RETRY = 0.25      # seconds between tries to subscribe a watched topic not in the graph yet
GRAPH_CHECK = 1.0         # seconds between checks of a watched topic's publishers' type
TERMINATED_KEEP = 60.0    # seconds a fired one-shot trigger stays readable (status "terminated")
REPLAY_MAX_BYTES = 256 * 1024  # an event larger than this is not kept for a stream opened later
ERROR_EVERY = 1.0         # seconds between two error events of one topic (undecodable messages)
SAVE_WAIT = 1.0
MAX_LIFETIME = 2**31 - 1
LEGACY_FILE = "triggers.json"    # an older gateway's store: imported once
LEGACY_MAX_BYTES = 64 * 2**20    # a larger one is not read
TARGET_MAX = 256 * 1024  # characters of a faults or logs trigger's target (the entity's node names, JSON)
TARGET_VALUE_MAX = 4096  # bytes of the JSON of an OnChangeTo target_value


# ---- conditions -----------------------------------------------------------------------------------
_NON_FINITE = {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}


def _number(value: Any) -> float | None:
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, str):
        return _NON_FINITE.get(value)
    return None


def same(a: Any, b: Any) -> bool:
    """JSON equality with IEEE numbers: 1 == 1.0, NaN == NaN (no change), a boolean is no number."""
    if isinstance(a, bool) or isinstance(b, bool):
        return isinstance(a, bool) and isinstance(b, bool) and a == b
    na, nb = _number(a), _number(b)
    if na is not None and nb is not None and not (isinstance(a, str) and isinstance(b, str)):
        return na == nb or (na != na and nb != nb)
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same(v, b[k]) for k, v in a.items())
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    return type(a) is type(b) and a == b


def in_range(value: Any, low: float, high: float) -> bool:
    number = _number(value)
    return number is not None and low <= number <= high  # NaN compares false: in no range


def fires(condition: dict[str, Any], previous: Any, current: Any) -> bool:
    """Whether ``condition`` fires on ``current`` after ``previous`` (MISSING: there was none)."""
    kind = condition["condition_type"]
    first = previous is jsonpointer.MISSING
    if kind == "OnChange":
        return first or not same(previous, current)
    if kind == "OnChangeTo":
        return same(current, condition["target_value"]) and (first or not same(previous, current))
    if first:
        return False
    low, high = condition["lower_bound"], condition["upper_bound"]
    was, now = in_range(previous, low, high), in_range(current, low, high)
    return (not was and now) if kind == "EnterRange" else (was and not now)


def check_condition(value: Any) -> dict[str, Any]:
    """The condition a client sent, as kept (only its own fields); IpcError("bad-request")."""
    if not isinstance(value, dict) or value.get("condition_type") not in CONDITIONS:
        raise IpcError("bad-request", "condition: expected an object whose condition_type is one of "
                       + ", ".join(CONDITIONS))
    kind = value["condition_type"]
    out: dict[str, Any] = {"condition_type": kind}
    if kind == "OnChangeTo":
        if "target_value" not in value:
            raise IpcError("bad-request", "condition: OnChangeTo needs target_value")
        try:
            size = len(json.dumps(value["target_value"], separators=(",", ":")).encode())
        except (TypeError, ValueError, RecursionError):
            raise IpcError("bad-request", "condition: target_value is not a JSON value") from None
        if size > TARGET_VALUE_MAX:
            raise IpcError("bad-request", f"condition: target_value too large ({size} bytes of JSON; "
                           f"at most {TARGET_VALUE_MAX})", {"max_bytes": TARGET_VALUE_MAX})
        out["target_value"] = value["target_value"]
    elif kind in ("EnterRange", "LeaveRange"):
        low, high = value.get("lower_bound"), value.get("upper_bound")
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                   for v in (low, high)) or low > high:
            raise IpcError("bad-request", "condition: lower_bound and upper_bound must be finite numbers, "
                                          "lower_bound <= upper_bound")
        out["lower_bound"], out["upper_bound"] = low, high
    return out


# ---- the trigger ------------------------------------------------------------------------------------
class Trigger:
    __slots__ = ("id", "collection", "entity_id", "resource", "source", "target", "bytes", "path",
                 "condition", "multishot", "persistent", "lifetime", "created_at_ns", "client", "status",
                 "deadline", "tokens", "previous", "seq", "last_event", "opened_seq", "size")

    FIELDS = ("id", "collection", "entity_id", "resource", "source", "target", "bytes", "path", "condition",
              "multishot", "persistent", "lifetime", "created_at_ns", "client", "status")

    def __init__(self, **fields: Any):
        for name in self.FIELDS:
            setattr(self, name, fields[name])
        self.deadline: float | None = None      # time.monotonic() of its expiry; None: no lifetime
        self.tokens = jsonpointer.parse(self.path)
        self.previous: Any = jsonpointer.MISSING
        self.seq = 0
        self.last_event: tuple[int, int, bytes | None, str | None] | None = None
        self.opened_seq = 0
        self.size = 0                           # bytes of its record, as last written

    @property
    def expires_at_ns(self) -> int | None:
        if self.deadline is None:
            return None
        return time.time_ns() + int((self.deadline - time.monotonic()) * 1e9)

    def wire(self) -> dict[str, Any]:
        out = {name: getattr(self, name) for name in self.FIELDS}
        out["expires_at_ns"] = self.expires_at_ns
        out["replayable"] = self.last_event is not None and self.last_event[1] > self.opened_seq
        return out

    def record(self) -> bytes:
        out = {name: getattr(self, name) for name in self.FIELDS}
        out["expires_at_ns"] = self.expires_at_ns
        return json.dumps(out, separators=(",", ":")).encode()


# ---- sources ------------------------------------------------------------------------------------------
class _TopicWatch:
    __slots__ = ("topic", "type_name", "cls", "sub", "triggers", "error_at")

    def __init__(self, topic: str):
        self.topic = topic
        self.type_name: str | None = None
        self.cls = None
        self.sub = None
        self.triggers: list[Trigger] = []
        self.error_at = 0.0


class DataSource:
    """Data items: one subscription per watched topic, every message taken and evaluated once."""

    kind = "data"

    def __init__(self, registry: TriggerRegistry):
        self.registry = registry
        self.node = registry.node
        self.endpoints = registry.endpoints
        self.stats = registry.stats
        self.watches: dict[str, _TopicWatch] = {}
        self.live: list[_TopicWatch] = []       # the watches with a subscription (polled every round)
        self._retry: Timer | None = None
        self._last_check = 0.0

    def active(self) -> bool:
        return bool(self.live)

    def attach(self, trigger: Trigger) -> None:
        watch = self.watches.get(trigger.target)
        if watch is None:
            watch = self.watches[trigger.target] = _TopicWatch(trigger.target)
        watch.triggers.append(trigger)
        if watch.sub is None:
            self.registry.executor.guarded(f"subscribing the trigger topic {watch.topic}", self._subscribe, watch)
            if watch.sub is None:
                self._arm_retry()

    def detach(self, trigger: Trigger) -> None:
        watch = self.watches.get(trigger.target)
        if watch is None or trigger not in watch.triggers:
            return
        watch.triggers.remove(trigger)
        if not watch.triggers:
            del self.watches[watch.topic]
            self._drop(watch)

    def close(self) -> None:
        for watch in list(self.watches.values()):
            self._drop(watch)
        self.watches.clear()

    # ---- subscriptions --------------------------------------------------------------------------
    def _subscribe(self, watch: _TopicWatch) -> None:
        infos = self.endpoints.publishers(watch.topic)
        if not infos:
            return
        types: dict[str, int] = {}
        for info in infos:
            types[info.topic_type] = types.get(info.topic_type, 0) + 1
        type_name = max(types, key=types.get)
        try:
            cls = msgtypes.load_type(type_name)
        except msgtypes.ConversionError:
            return
        profile = qos.match_qos([i for i in infos if i.topic_type == type_name])
        profile.depth = TRIGGER_DEPTH
        watch.sub = self.node.create_subscription(cls, watch.topic, _never_called, profile)
        watch.type_name, watch.cls = type_name, cls
        self.live.append(watch)
        log.debug("triggers: watching %s [%s]", watch.topic, type_name)

    def _drop(self, watch: _TopicWatch) -> None:
        if watch in self.live:
            self.live.remove(watch)
        if watch.sub is not None:
            try:
                self.node.destroy_subscription(watch.sub)
            except Exception:
                log.exception("destroying the trigger subscription of %s failed", watch.topic)
            watch.sub = None

    def _arm_retry(self) -> None:
        if self._retry is None:
            self._retry = self.registry.executor.call_later(PENDING_RETRY, self._retry_pending)

    def _retry_pending(self) -> None:
        self._retry = None
        pending = [w for w in self.watches.values() if w.sub is None]
        for watch in pending:
            self.registry.executor.guarded(f"subscribing the trigger topic {watch.topic}", self._subscribe, watch)
        if any(w.sub is None for w in self.watches.values()):
            self._arm_retry()

    def _check_types(self) -> None:
        """A watched topic whose publishers changed type is subscribed again with the new one."""
        for watch in list(self.live):
            infos = self.endpoints.publishers(watch.topic)
            if infos and watch.type_name not in {i.topic_type for i in infos}:
                log.info("triggers: %s changed type; subscribing again", watch.topic)
                self._drop(watch)
                self._subscribe(watch)
                if watch.sub is None:
                    self._arm_retry()

    # ---- every round ------------------------------------------------------------------------------
    def poll(self) -> None:
        now = time.monotonic()
        if now - self._last_check >= GRAPH_CHECK:
            self._last_check = now
            self.registry.executor.guarded("the trigger topics' type check", self._check_types)
        until = now + ROUND_BUDGET
        for watch in list(self.live):
            if watch.sub is not None:
                self.registry.executor.guarded(f"the triggers of {watch.topic}", self._drain, watch, until)
        if len(self.live) > 1:  # the next round starts with the next topic: none waits behind a busy one
            self.live.append(self.live.pop(0))

    def _drain(self, watch: _TopicWatch, until: float) -> None:
        handle = watch.sub.handle
        for _ in range(TAKES_PER_ROUND):
            if watch.sub is None or not watch.triggers or time.monotonic() >= until:
                return
            try:
                taken = handle.take_message(watch.cls, False)
            except Exception:
                self._failed(watch, f"A message on {watch.topic} cannot be decoded as {watch.type_name}")
                continue
            if taken is None:
                return
            msg, info = taken
            self.stats.trigger_messages += 1
            stamp = info.get("received_timestamp") or time.time_ns()
            try:
                texts = {"array": to_json(msg, "array")}
                doc = orjson.loads(texts["array"])
            except Exception:
                self._failed(watch, f"A message on {watch.topic} could not be converted to JSON")
                continue
            for trigger in list(watch.triggers):
                value = jsonpointer.resolve(doc, trigger.tokens)
                if value is jsonpointer.MISSING:
                    continue
                previous, trigger.previous = trigger.previous, value
                if fires(trigger.condition, previous, value):
                    text = texts.get(trigger.bytes)
                    if text is None:
                        text = texts[trigger.bytes] = to_json(msg, trigger.bytes)
                    self.registry.fire(trigger, stamp, payload=text)

    def _failed(self, watch: _TopicWatch, message: str) -> None:
        self.stats.undecodable_messages += 1
        now = time.monotonic()
        if now - watch.error_at < ERROR_EVERY:
            return
        watch.error_at = now
        for trigger in list(watch.triggers):
            self.registry.fire(trigger, time.time_ns(), error=message)


# Observable resource kinds: collection -> source.  Faults and logs join here once they exist.
SOURCES: dict[str, type] = {"data": DataSource}


def _never_called(_msg) -> None:  # pragma: no cover - trigger subscriptions are never spun
    pass


# ---- the registry ---------------------------------------------------------------------------------------
class TriggerRegistry:
    def __init__(self, node, executor: RosExecutor, stats: Stats, endpoints: Endpoints,
                 send: Callable[[list[bytes]], None], store: FaultStore, *, max_triggers: int,
                 max_per_client: int, max_bytes: int, legacy_path: str = ""):
        self.node = node
        self.executor = executor
        self.stats = stats
        self.endpoints = endpoints
        self._send = send
        self.max_triggers = max_triggers
        self.max_per_client = max_per_client
        self.max_bytes = max_bytes
        self.bytes = 0                          # of the records of the triggers held
        self.triggers: dict[str, Trigger] = {}
        self._timers: dict[str, Timer] = {}
        self.per_client: dict[str, int] = {}
        self.store = store
        self.legacy_path = legacy_path
        self.sources = {kind: cls(self) for kind, cls in SOURCES.items()}
        for kind, source in self.sources.items():
            executor.add_poller(f"{kind} triggers", source.active, source.poll)
        stats.max_triggers = max_triggers
        stats.max_trigger_bytes = max_bytes
        self.handlers: dict[str, Callable[[Task], None]] = {
            "trig_create": self._cmd_create, "trig_list": self._cmd_list, "trig_get": self._cmd_get,
            "trig_update": self._cmd_update, "trig_delete": self._cmd_delete, "trig_open": self._cmd_open,
        }

    # ---- boot and end ---------------------------------------------------------------------------
    def restore(self, restart: bool) -> None:
        """The triggers of the store: all of them after a ROS worker restart, the persistent ones at a
        new gateway's first boot.  Expired and terminated ones are dropped (their rows deleted)."""
        now_ns = time.time_ns()
        kept = 0
        rows = self.store.load_triggers()
        items = [item for _, item in rows if isinstance(item, dict)] + self._legacy()
        for item in items:
            try:
                fields = {name: item[name] for name in Trigger.FIELDS}
                if fields["status"] != "active" or fields["source"] not in self.sources \
                        or not (restart or fields["persistent"] is True):
                    continue
                fields["condition"] = check_condition(fields["condition"])
                if not _valid_record(fields):
                    continue
                check = getattr(self.sources[fields["source"]], "check_target", None)  # faults and logs
                if check is not None:
                    check(fields["target"])
                trigger = Trigger(**fields)
            except (KeyError, TypeError, ValueError, IpcError):
                continue
            expires = item.get("expires_at_ns")
            if expires is not None:
                if not isinstance(expires, int) or expires <= now_ns:
                    continue
                trigger.deadline = time.monotonic() + (expires - now_ns) / 1e9
            if len(self.triggers) >= self.max_triggers or trigger.id in self.triggers:
                continue
            self._add(trigger)
            kept += 1
        for trigger_id, _ in rows:  # what was not restored is not kept either
            if trigger_id not in self.triggers:
                self.store.put_trigger(trigger_id, None)
        if kept:
            log.info("restored %d triggers", kept)

    def _legacy(self) -> list[dict[str, Any]]:
        """The triggers of an older gateway's ``triggers.json``, read once (the file is then renamed)."""
        path = self.legacy_path
        try:
            if not path or not os.path.isfile(path) or os.path.getsize(path) > LEGACY_MAX_BYTES:
                return []
            with open(path, "rb") as fh:
                data = json.loads(fh.read())
            os.replace(path, path + ".imported")
        except (OSError, ValueError) as exc:
            log.warning("could not import the triggers of %s: %s", path, exc)
            return []
        items = data.get("triggers") if isinstance(data, dict) else None
        found = [t for t in items if isinstance(t, dict)] if isinstance(items, list) else []
        log.info("imported %d triggers from %s (now %s.imported)", len(found), path, path)
        return found

    def close(self) -> None:
        for source in self.sources.values():
            self.executor.guarded("closing the trigger sources", source.close)

    # ---- commands ----------------------------------------------------------------------------------
    def _when_saved(self, task: Task, result: dict[str, Any]) -> Callable[[], None]:
        """What the store calls (its thread) once a change is written: ``task`` is answered (on the ROS
        thread); after ``SAVE_WAIT`` s it is answered anyway (a slow disk: the change holds in memory)."""
        done = [False]

        def once() -> None:
            if not done[0]:
                done[0] = True
                timer.cancel()
                task.reply(result)

        timer = self.executor.call_later(SAVE_WAIT, once)
        return lambda: self.executor.post(once)

    def _get(self, args: dict) -> Trigger:
        trigger = self.triggers.get(args.get("id")) if isinstance(args.get("id"), str) else None
        if trigger is None or trigger.collection != args.get("collection") \
                or trigger.entity_id != args.get("entity_id"):
            raise IpcError("no-such-trigger", "Trigger not found", {"trigger_id": str(args.get("id"))[:100]})
        return trigger

    def _cmd_create(self, task: Task) -> None:
        args = task.args
        source = args.get("source")
        if source not in self.sources:
            raise IpcError("bad-request", "source: expected one of " + ", ".join(self.sources))
        strings = {}
        for name, limit in (("collection", 64), ("entity_id", 256), ("resource", 4096),
                            ("target", 4096 if source == "data" else TARGET_MAX), ("bytes", 16)):
            value = args.get(name)
            if not isinstance(value, str) or not value or len(value) > limit:
                raise IpcError("bad-request", f"{name}: expected a string of 1 to {limit} characters")
            strings[name] = value
        if strings["bytes"] not in protocol.BYTES_MODES:
            raise IpcError("bad-request", "bytes: expected 'array' or 'base64'")
        check = getattr(self.sources[source], "check_target", None)  # faults and logs: the entity's scope
        if check is not None:
            check(strings["target"])
        if source == "data":
            try:
                strings["target"] = normalize_topic(strings["target"])
            except InvalidTopic as exc:
                raise IpcError("invalid-topic", str(exc), {"topic": strings["target"][:300]}) from None
        path = args.get("path", "")
        try:
            jsonpointer.parse(path)
        except ValueError as exc:
            raise IpcError("bad-request", f"path: {exc}") from None
        lifetime = args.get("lifetime")
        if lifetime is not None and (isinstance(lifetime, bool) or not isinstance(lifetime, int)
                                     or not 0 < lifetime <= MAX_LIFETIME):
            raise IpcError("bad-request", "lifetime: expected a positive integer")
        flags = {}
        for name in ("multishot", "persistent"):
            value = args.get(name, False)
            if not isinstance(value, bool):
                raise IpcError("bad-request", f"{name}: expected a boolean")
            flags[name] = value
        client = args.get("client") if isinstance(args.get("client"), str) else ""
        client = client[:256]
        if len(self.triggers) >= self.max_triggers:
            raise IpcError("triggers-full", f"The gateway already holds {self.max_triggers} triggers "
                           "(max_triggers); delete one or retry later", {"max_triggers": self.max_triggers})
        if client and self.per_client.get(client, 0) >= self.max_per_client:
            raise IpcError("triggers-full", f"This client ({client}) already holds {self.max_per_client} "
                           "triggers (max_triggers_per_client); delete one or retry later",
                           {"max_triggers_per_client": self.max_per_client})
        trigger = Trigger(id="trig_" + secrets.token_hex(8), source=source, path=path,
                          condition=check_condition(args.get("condition")), lifetime=lifetime,
                          created_at_ns=time.time_ns(), client=client, status="active", **strings, **flags)
        if lifetime is not None:
            trigger.deadline = time.monotonic() + lifetime
        size = len(trigger.record())
        if self.bytes + size > self.max_bytes:
            raise IpcError("triggers-full", f"The triggers held take {self.bytes} of the {self.max_bytes} bytes "
                           f"the gateway keeps for them (max_trigger_bytes); this one needs {size}: delete one "
                           "or retry later", {"max_trigger_bytes": self.max_bytes})
        self._add(trigger, self._when_saved(task, trigger.wire()))
        self.stats.triggers_created += 1

    def _cmd_list(self, task: Task) -> None:
        args = task.args
        task.reply({"items": [t.wire() for t in sorted(self.triggers.values(), key=lambda t: t.created_at_ns)
                              if t.collection == args.get("collection") and t.entity_id == args.get("entity_id")]})

    def _cmd_get(self, task: Task) -> None:
        task.reply(self._get(task.args).wire())

    def _cmd_open(self, task: Task) -> None:
        """A stream opens: the trigger, and the newest event no stream was opened for yet."""
        trigger = self._get(task.args)
        out = trigger.wire()
        event = trigger.last_event
        if event is not None and event[1] > trigger.opened_seq:
            stamp, seq, payload, error = event
            out["replay"] = {"ts": stamp, "seq": seq, "payload": payload, "error": error,
                             "last": trigger.status != "active"}
        trigger.opened_seq = trigger.seq
        task.reply(out)

    def _cmd_update(self, task: Task) -> None:
        trigger = self._get(task.args)
        lifetime = task.args.get("lifetime")
        if isinstance(lifetime, bool) or not isinstance(lifetime, int) or not 0 < lifetime <= MAX_LIFETIME:
            raise IpcError("bad-request", "lifetime: expected a positive integer")
        trigger.lifetime = lifetime
        trigger.deadline = time.monotonic() + lifetime
        if trigger.status == "active":
            self._arm(trigger)
        self._changed(trigger, self._when_saved(task, trigger.wire()))

    def _cmd_delete(self, task: Task) -> None:
        self._remove(self._get(task.args), "deleted", self._when_saved(task, {}))

    # ---- firing ------------------------------------------------------------------------------------
    def fire(self, trigger: Trigger, stamp: int, *, payload: bytes | None = None, error: str | None = None) -> None:
        if trigger.status != "active":
            return
        trigger.seq += 1
        last = error is None and not trigger.multishot
        keep = payload is None or len(payload) <= REPLAY_MAX_BYTES
        trigger.last_event = (stamp, trigger.seq, payload, error) if keep else None
        meta: dict[str, Any] = {"ts": stamp, "seq": trigger.seq}
        if error is not None:
            meta["error"] = error
        if last:
            meta["last"] = True
        self._send([events.trigger_event_key(trigger.id), protocol.pack(meta), payload or b""])
        self.stats.trigger_events += 1
        if last:
            self._terminate(trigger)

    def _terminate(self, trigger: Trigger) -> None:
        trigger.status = "terminated"
        self.sources[trigger.source].detach(trigger)
        timer = self._timers.pop(trigger.id, None)
        if timer is not None:
            timer.cancel()
        self._timers[trigger.id] = self.executor.call_later(
            TERMINATED_KEEP, lambda: self._remove(trigger, "expired"))
        self._changed(trigger)

    # ---- the set ------------------------------------------------------------------------------------
    def _add(self, trigger: Trigger, then: Callable[[], None] | None = None) -> None:
        # Sequence numbers go on from the wall clock, so a stream that stays open across a ROS
        # worker restart does not take the restored trigger's events for ones it already sent.
        trigger.seq = trigger.opened_seq = max(trigger.seq, time.time_ns())
        self.triggers[trigger.id] = trigger
        if trigger.client:
            self.per_client[trigger.client] = self.per_client.get(trigger.client, 0) + 1
        self.sources[trigger.source].attach(trigger)
        self._arm(trigger)
        self._changed(trigger, then)

    def _changed(self, trigger: Trigger, then: Callable[[], None] | None = None) -> None:
        """Its row written again (``then`` once it is); the size of what is held counted again."""
        record = trigger.record()
        self.bytes += len(record) - trigger.size
        trigger.size = len(record)
        self.store.put_trigger(trigger.id, record, then)
        self._gauges()

    def _gauges(self) -> None:
        self.stats.active_triggers = sum(1 for t in self.triggers.values() if t.status == "active")
        self.stats.trigger_bytes = self.bytes

    def _arm(self, trigger: Trigger) -> None:
        old = self._timers.pop(trigger.id, None)
        if old is not None:
            old.cancel()
        if trigger.deadline is not None:
            self._timers[trigger.id] = self.executor.call_later(
                max(0.0, trigger.deadline - time.monotonic()), lambda: self._expire(trigger))

    def _expire(self, trigger: Trigger) -> None:
        if self.triggers.get(trigger.id) is not trigger or trigger.deadline is None:
            return
        if trigger.deadline > time.monotonic() + 0.001:  # woken early (PUT meanwhile): arm again
            self._arm(trigger)
            return
        self._remove(trigger, "expired")

    def _remove(self, trigger: Trigger, event: str, then: Callable[[], None] | None = None) -> None:
        if self.triggers.pop(trigger.id, None) is None:
            if then is not None:
                then()
            return
        self.bytes -= trigger.size
        trigger.size = 0
        if trigger.client:
            held = self.per_client.get(trigger.client, 0) - 1
            if held > 0:
                self.per_client[trigger.client] = held
            else:
                self.per_client.pop(trigger.client, None)
        self.sources[trigger.source].detach(trigger)
        timer = self._timers.pop(trigger.id, None)
        if timer is not None:
            timer.cancel()
        self.store.put_trigger(trigger.id, None, then)
        self._gauges()
        self._send([events.trigger_control_key(trigger.id), protocol.pack({"event": event, "id": trigger.id})])


def _valid_record(fields: dict[str, Any]) -> bool:
    """A stored trigger's fields have the types a created one has (the file may have been edited)."""
    strings = ("id", "collection", "entity_id", "resource", "source", "target", "bytes", "path", "client")
    lifetime = fields["lifetime"]
    return (all(isinstance(fields[name], str) for name in strings) and fields["id"].startswith("trig_")
            and fields["bytes"] in protocol.BYTES_MODES
            and all(isinstance(fields[name], bool) for name in ("multishot", "persistent"))
            and isinstance(fields["created_at_ns"], int)
            and (lifetime is None or (isinstance(lifetime, int) and not isinstance(lifetime, bool)
                                      and 0 < lifetime <= MAX_LIFETIME)))


def events_sender(streams) -> Callable[[list[bytes]], None]:
    """The events channel's send (the cyclic streams' PUB socket), for the triggers' frames."""
    def send(frames: list[bytes]) -> None:
        try:
            streams.send(frames)
        except zmq.ZMQError:
            pass
    return send


# faults and logs triggers: two more observable kinds, event-driven (rosworker/triggers/sources.py)
from .sources import FaultSource, LogSource  # noqa: E402  (it imports this module's names lazily)

SOURCES.update(faults=FaultSource, logs=LogSource)
