"""SOVD triggers: the set, their commands and their events (``trig_*``, ``ipc/PROTOCOL.md``).

Every method runs on the ROS thread, except the store's writer (a thread of
its own).  The ROS worker is the single owner of the triggers, so that one
made through one HTTP worker streams through any other.

What a trigger observes is a collection another family provides through the
core's notifier (``data``: every message of a topic; ``faults``; ``logs``):
the triggers of one ``(source, target)`` are attached there as one group
(``sources.py``), whose conditions (``conditions.py``) are evaluated on every
change; this module knows no family.

Events.  Only firing crosses to the HTTP workers, on the events channel, once
per change and bytes mode however many triggers it fired (:meth:`TriggerRegistry.fire`):
``t|g|<bytes mode>|<source>|<digest of the target>|`` (``events.trigger_group_key``)
+ msgpack ``{"ts", "fired": [[id, seq, last], ...], "error"?}`` + the JSON of
the change; each HTTP worker frames it for the streams of each trigger in
``fired``.  A one-shot trigger's event is its last (``last``); it is then
``terminated`` and kept ``TERMINATED_KEEP`` s, so a stream opened just
after it fired still gets that event (``trig_open`` hands the newest event
that no stream has been opened for yet).  Deletion and expiry are control
frames ``t|c|<id>|``.

Store.  A trigger's record is made once per change and written as one row of
the state directory's store (``store.py``); a command that changed a trigger
is answered once its row is written.  A restarted ROS worker restores them
all; a new gateway only the ``persistent`` ones (the others' rows are
deleted).  They are restored before their topics are discovered (a topic is
subscribed once it shows).

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
import secrets
import time
from collections.abc import Callable
from typing import Any

from ipc import events, jsonpointer, protocol
from ipc.errors import IpcError

from ..core import args
from ..core.executor import RosExecutor
from ..core.notifier import ChangeNotifier
from ..core.perclient import PerClient
from ..core.stats import Stats
from ..core.task import Task, Timer
from ..core.writer import once_written
from .conditions import check_condition
from .sources import TriggerGroup
from .store import MAX_LIFETIME, TriggerStore, valid_record

log = logging.getLogger("sovd.rosworker.triggers")

TERMINATED_KEEP = 60.0    # seconds a fired one-shot trigger stays readable (status "terminated")
REPLAY_MAX_BYTES = 256 * 1024  # an event larger than this is not kept for a stream opened later
SAVE_WAIT = 1.0           # seconds a change waits for its row to be written before it is answered anyway


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


# ---- the registry ---------------------------------------------------------------------------------------
class TriggerRegistry:
    def __init__(self, executor: RosExecutor, stats: Stats, notifier: ChangeNotifier,
                 send: Callable[[list[bytes]], None], store: TriggerStore, *, max_triggers: int,
                 max_per_client: int, max_bytes: int):
        self.executor = executor
        self.stats = stats
        self.notifier = notifier
        self._send = send
        self.max_triggers = max_triggers
        self.max_per_client = max_per_client
        self.max_bytes = max_bytes
        self.bytes = 0                          # of the records of the triggers held
        self.triggers: dict[str, Trigger] = {}
        self._timers: dict[str, Timer] = {}
        self.per_client = PerClient()
        self.store = store
        self._groups: dict[tuple[str, str], TriggerGroup] = {}   # (source, target) -> attached to the collection
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
        rows = self.store.rows()
        items = [item for _, item in rows if isinstance(item, dict)] + self.store.legacy()
        for item in items:
            try:
                fields = {name: item[name] for name in Trigger.FIELDS}
                if fields["status"] != "active" or fields["source"] not in self.notifier.collections \
                        or not (restart or fields["persistent"] is True):
                    continue
                fields["condition"] = check_condition(fields["condition"])
                if not valid_record(fields):
                    continue
                fields["target"] = self.notifier.get(fields["source"]).check_target(fields["target"])
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
                self.store.put(trigger_id, None)
        if kept:
            log.info("restored %d triggers", kept)

    def close(self) -> None:
        """Every trigger detached from its collection (their rows stay in the store)."""
        for trigger in list(self.triggers.values()):
            self._detach(trigger)

    # ---- commands ----------------------------------------------------------------------------------
    def _when_saved(self, task: Task, result: dict[str, Any]) -> Callable[[], None]:
        """``task`` answered once the change is written, or after ``SAVE_WAIT`` s (a slow disk: the change
        holds in memory)."""
        return once_written(self.executor, lambda: task.reply(result), SAVE_WAIT)

    def _get(self, a: dict) -> Trigger:
        trigger = self.triggers.get(a.get("id")) if isinstance(a.get("id"), str) else None
        if trigger is None or trigger.collection != a.get("collection") or trigger.entity_id != a.get("entity_id"):
            raise IpcError("no-such-trigger", "Trigger not found", {"trigger_id": str(a.get("id"))[:100]})
        return trigger

    def _cmd_create(self, task: Task) -> None:
        a = task.args
        source = a.get("source")
        observable = self.notifier.get(source)  # the collection it observes: "bad-request" when none has it
        strings = {name: args.string(a, name, limit=limit)
                   for name, limit in (("collection", 64), ("entity_id", 256), ("resource", 4096),
                                       ("target", observable.max_target), ("bytes", 16))}
        args.bytes_mode(strings)
        strings["target"] = observable.check_target(strings["target"])
        path = a.get("path", "")
        try:
            jsonpointer.parse(path)
        except ValueError as exc:
            raise IpcError("bad-request", f"path: {exc}") from None
        lifetime = args.optional(a, "lifetime", args.integer, 1, MAX_LIFETIME, "a positive integer")
        flags = {name: args.flag(a, name) for name in ("multishot", "persistent")}
        client = a.get("client") if isinstance(a.get("client"), str) else ""
        client = client[:256]
        if len(self.triggers) >= self.max_triggers:
            raise IpcError("triggers-full", f"The gateway already holds {self.max_triggers} triggers "
                           "(max_triggers); delete one or retry later", {"max_triggers": self.max_triggers})
        if self.per_client.held(client) >= self.max_per_client:
            raise IpcError("triggers-full", f"This client ({client}) already holds {self.max_per_client} "
                           "triggers (max_triggers_per_client); delete one or retry later",
                           {"max_triggers_per_client": self.max_per_client})
        trigger = Trigger(id="trig_" + secrets.token_hex(8), source=source, path=path,
                          condition=check_condition(a.get("condition")), lifetime=lifetime,
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
        a = task.args
        task.reply({"items": [t.wire() for t in sorted(self.triggers.values(), key=lambda t: t.created_at_ns)
                              if t.collection == a.get("collection") and t.entity_id == a.get("entity_id")]})

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
        lifetime = args.integer(task.args, "lifetime", 1, MAX_LIFETIME, "a positive integer")
        trigger.lifetime = lifetime
        trigger.deadline = time.monotonic() + lifetime
        if trigger.status == "active":
            self._arm(trigger)
        self._changed(trigger, self._when_saved(task, trigger.wire()))

    def _cmd_delete(self, task: Task) -> None:
        self._remove(self._get(task.args), "deleted", self._when_saved(task, {}))

    # ---- firing ------------------------------------------------------------------------------------
    def fire(self, stamp: int, fired: list[Trigger], *, payload: Callable[[str], bytes] | None = None,
             error: str | None = None) -> None:
        """One change fired ``fired`` (triggers of one group: one source and target): one frame per bytes
        mode among them carries the change (``payload(mode)``, made once) and, for each trigger, its id,
        its ``seq`` and whether the event is its last (a one-shot's: the trigger is then terminated)."""
        modes: dict[str, list[Trigger]] = {}
        for trigger in fired:
            if trigger.status == "active":
                modes.setdefault(trigger.bytes, []).append(trigger)
        for mode, triggers in modes.items():
            body = payload(mode) if payload is not None and error is None else None
            keep = body is None or len(body) <= REPLAY_MAX_BYTES
            entries, ended = [], []
            for trigger in triggers:
                trigger.seq += 1
                last = error is None and not trigger.multishot
                trigger.last_event = (stamp, trigger.seq, body, error) if keep else None
                entries.append([trigger.id, trigger.seq, last])
                if last:
                    ended.append(trigger)
            meta: dict[str, Any] = {"ts": stamp, "fired": entries}
            if error is not None:
                meta["error"] = error
            key = events.trigger_group_key(triggers[0].source, mode, triggers[0].target)
            self._send([key, protocol.pack(meta), body or b""])
            self.stats.trigger_frames += 1
            self.stats.trigger_events += len(entries)
            for trigger in ended:
                self._terminate(trigger)

    def _terminate(self, trigger: Trigger) -> None:
        trigger.status = "terminated"
        self._detach(trigger)
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
        self.per_client.take(trigger.client)
        group = self._groups.get((trigger.source, trigger.target))
        if group is None:
            group = self._groups[trigger.source, trigger.target] = TriggerGroup(trigger.source, trigger.target,
                                                                                self.fire)
            self.notifier.observe(trigger.source, group)
        group.triggers.append(trigger)
        self._arm(trigger)
        self._changed(trigger, then)

    def _detach(self, trigger: Trigger) -> None:
        group = self._groups.get((trigger.source, trigger.target))
        if group is None or trigger not in group.triggers:
            return
        group.triggers.remove(trigger)
        if not group.triggers:  # the last of its group: the collection no longer calls it
            del self._groups[trigger.source, trigger.target]
            self.notifier.forget(trigger.source, group)

    def _changed(self, trigger: Trigger, then: Callable[[], None] | None = None) -> None:
        """Its row written again (``then`` once it is); the size of what is held counted again."""
        record = trigger.record()
        self.bytes += len(record) - trigger.size
        trigger.size = len(record)
        self.store.put(trigger.id, record, then)
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
        self.per_client.give(trigger.client)
        self._detach(trigger)
        timer = self._timers.pop(trigger.id, None)
        if timer is not None:
            timer.cancel()
        self.store.put(trigger.id, None, then)
        self._gauges()
        self._send([events.trigger_control_key(trigger.id), protocol.pack({"event": event, "id": trigger.id})])


