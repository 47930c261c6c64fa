"""Cyclic subscriptions: the registry (its caps, expiry, updates, restart state and control events).

Every method runs on the ROS thread.  The ROS worker is the single owner of
the subscriptions (SOVD "cyclic subscriptions"), so that a POST answered by
one HTTP worker streams through any other, and the registry survives an HTTP
worker's restart; it is kept in the restart state too, so it survives the
ROS worker's.

What a subscription watches is framed by the sampler of its kind (the core's
samplers, ``core/samplers.py``): ``data`` (a topic: the data family's ticks),
``execution``, ``parameter``; this registry knows no family.  It hands each
subscription to its sampler when it is added (``watch``) and takes it back when
it goes (``unwatch``); a sampler may end one (a goal that finished), as an
expiry does.

Control events (``updated``, ``deleted``, ``expired``) and a heartbeat go on
the same socket, so HTTP workers end or retime their streams at once.

Expiry runs on the monotonic clock (``Subscription.deadline``): a step of the
wall clock neither ends a subscription early nor keeps it for ever.
``expires_at_ns`` is derived from it for the answers, and for the restart
state, where the wall clock is the clock the next worker shares.

Saving: each subscription's restart record (its JSON) is made once, when it
is created or changed; after a change ``save()`` hands the list of records
(a copy of references, not a serialisation) to the restart state's writer
thread (``rosworker/core/state.py``), and a command that changed the registry is
answered once the writer has written it (``when_saved``: ``save(then)``): a
subscription that was answered survives a ROS worker killed right after, and
the ROS thread's cost of a change does not grow with the registry.
"""

from __future__ import annotations

import json
import logging
import secrets
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

from ipc import events, protocol
from ipc.errors import IpcError

from ..core.events import EventsChannel
from ..core.executor import RosExecutor
from ..core.perclient import PerClient
from ..core.samplers import SamplerRegistry
from ..core.stats import Stats
from ..core.task import Timer
from ..core.writer import once_written

log = logging.getLogger("sovd.rosworker.subscriptions")

SAVE_WAIT = 1.0     # seconds a changed registry waits for the writer before it is answered anyway


def wall_minus_monotonic_ns() -> int:
    """The wall clock minus the monotonic one, in ns: what turns a deadline into ``expires_at``.

    The two clocks are read as a pair, and again when the thread was preempted between the
    reads (a loaded robot): a pair read a scheduler slice apart would shift a displayed or
    restored expiry by that slice.
    """
    best = None
    for _ in range(3):
        before = time.monotonic_ns()
        wall = time.time_ns()
        after = time.monotonic_ns()
        if best is None or after - before < best[0]:
            best = (after - before, wall - (before + after) // 2)
        if after - before < 200_000:
            break
    return best[1]


@dataclass
class Subscription:
    id: str
    collection: str
    entity_id: str
    resource: str
    topic: str
    bytes: str
    interval: str
    duration: int
    created_at_ns: int
    client: str = ""        # the client address that made it ("" when the HTTP side did not say)
    # the sampler that frames it (core/samplers.py): "data" (a topic), "execution", "parameter" ..., and what it
    # names
    kind: str = "data"
    target: dict[str, Any] = field(default_factory=dict)
    deadline: float = field(default=0.0, compare=False)  # time.monotonic() at which it expires

    @property
    def expires_at_ns(self) -> int:
        """The wall-clock time of ``deadline``, for display and the restart state only."""
        return wall_minus_monotonic_ns() + int(self.deadline * 1e9)

    def wire(self) -> dict[str, Any]:
        """What the ``sub_*`` commands answer (the HTTP side makes the SOVD body of it)."""
        out = asdict(self)
        del out["deadline"]
        return {**out, "expires_at_ns": self.expires_at_ns, "key": self.key}

    def record(self) -> bytes:
        """Its restart record: the fields, with the deadline as wall-clock ``expires_at_ns``."""
        out = asdict(self)
        del out["deadline"]
        out["expires_at_ns"] = self.expires_at_ns
        return json.dumps(out, separators=(",", ":")).encode()

    @property
    def key(self) -> bytes:
        if self.kind != "data":  # a feed's frames are its own (one timer per subscription)
            return events.data_key(self.interval, self.kind, self.id)
        return events.data_key(self.interval, self.bytes, self.topic)


def _target(target: Any) -> dict[str, Any]:
    """What a subscription of another kind than ``data`` names (its sampler checks the rest)."""
    target = target if target is not None else {}
    if not isinstance(target, dict) or len(target) > 8 or any(
            not isinstance(k, str) or not (v is None or isinstance(v, str) and len(v) <= 4096)
            for k, v in target.items()):
        raise IpcError("bad-request", "target: expected at most 8 strings of up to 4096 characters")
    return target


def _saved_at_once(then: Callable[[], None] | None = None) -> None:
    if then is not None:
        then()


class StreamRegistry:
    def __init__(self, executor: RosExecutor, events_: EventsChannel, samplers: SamplerRegistry, stats: Stats, *,
                 max_subscriptions: int, max_duration: int, max_per_client: int | None = None,
                 save: Callable[[Callable[[], None] | None], None] | None = None):
        self.executor = executor
        self.events = events_
        self.samplers = samplers
        self.stats = stats
        self.max_subscriptions = max_subscriptions
        self.max_per_client = max_per_client or max_subscriptions
        self.max_duration = max_duration
        self.subs: dict[str, Subscription] = {}
        self._records: dict[str, bytes] = {}  # id -> Subscription.record(), made when it changes
        self.version = 0                      # bumped at each change of the registry
        self.per_client = PerClient()
        self._expiry: dict[str, Timer] = {}
        # save(): after every change of the registry, hands the records to the restart state's
        # writer; save(then) also runs ``then`` once they are written (see when_saved).
        # Without it (a registry that is not kept), ``then`` runs at once.
        self._save = save or _saved_at_once
        stats.max_subscriptions = max_subscriptions

    def restore(self, saved: list[dict[str, Any]]) -> None:
        """Subscriptions of a previous worker (restart state); the expired ones are dropped."""
        offset = wall_minus_monotonic_ns()
        for item in saved:
            item = dict(item)
            expires_at_ns = item.pop("expires_at_ns", None)
            item.pop("deadline", None)
            try:
                sub = Subscription(**item)
            except TypeError:
                continue
            if not isinstance(expires_at_ns, int) or isinstance(expires_at_ns, bool):
                continue
            sub.deadline = (expires_at_ns - offset) / 1e9  # the wall clock is the one both workers share
            if sub.kind not in self.samplers.kinds:  # a kind no family streams (any more)
                continue
            if sub.deadline > time.monotonic() and sub.interval in events.INTERVALS \
                    and len(self.subs) < self.max_subscriptions and self.per_client.held(sub.client) < self.max_per_client:
                self._add(sub)
        if self.subs:
            log.info("restored %d cyclic subscriptions from before the restart", len(self.subs))

    def saved(self) -> list[dict[str, Any]]:
        return [json.loads(r) for r in self._records.values()]

    def records(self) -> list[bytes]:
        """The restart records (JSON texts made at each change): a copy of references, O(n) pointers."""
        return list(self._records.values())

    def when_saved(self, then: Callable[[], None]) -> None:
        """Run ``then`` (a command's reply) once the latest change is written, or after SAVE_WAIT."""
        self._save(once_written(self.executor, then, SAVE_WAIT, "the restart state"))

    # ---- commands ---------------------------------------------------------------------------
    def create(self, collection: str, entity_id: str, resource: str, topic: str, mode: str, interval: str,
               duration: int, client: str = "", kind: str = "data",
               target: dict[str, Any] | None = None) -> dict[str, Any]:
        if len(self.subs) >= self.max_subscriptions:
            raise IpcError("subscriptions-full",
                           f"The gateway already holds {self.max_subscriptions} cyclic subscriptions "
                           "(max_subscriptions); delete one or retry later",
                           {"max_subscriptions": self.max_subscriptions})
        if self.per_client.held(client) >= self.max_per_client:
            raise IpcError("subscriptions-full",
                           f"This client ({client}) already holds {self.max_per_client} cyclic subscriptions "
                           "(max_subscriptions_per_client); delete one or retry later",
                           {"max_subscriptions_per_client": self.max_per_client})
        target = _target(target)
        sub = Subscription(id="sub_" + secrets.token_hex(8), collection=collection, entity_id=entity_id,
                           resource=resource, topic=topic, bytes=mode, interval=interval, duration=duration,
                           created_at_ns=time.time_ns(), client=client, deadline=time.monotonic() + duration,
                           kind=kind, target=target)
        self.samplers.get(kind).check(sub)  # what it names exists (else IpcError)
        self._add(sub)
        self.stats.subscriptions_created += 1
        self._save()
        return sub.wire()

    def get(self, collection: str, entity_id: str, sub_id: str) -> Subscription:
        """The subscription, if it belongs to this entity (else ``no-such-subscription``)."""
        sub = self.subs.get(sub_id)
        if sub is None or sub.collection != collection or sub.entity_id != entity_id:
            raise IpcError("no-such-subscription", "Subscription not found", {"subscription_id": sub_id})
        return sub

    def listing(self, collection: str, entity_id: str) -> list[dict[str, Any]]:
        return [s.wire() for s in sorted(self.subs.values(), key=lambda s: s.created_at_ns)
                if s.collection == collection and s.entity_id == entity_id]

    def update(self, collection: str, entity_id: str, sub_id: str, interval: str | None,
               duration: int | None) -> dict[str, Any]:
        sub = self.get(collection, entity_id, sub_id)
        self._unwatch(sub)
        if interval is not None:
            sub.interval = interval
        if duration is not None:
            sub.duration = duration
            sub.deadline = time.monotonic() + duration
            self._arm_expiry(sub)
        self._watch(sub)
        self._records[sub.id] = sub.record()
        self.version += 1
        self._control(sub, "updated")
        self._save()
        return sub.wire()

    def delete(self, collection: str, entity_id: str, sub_id: str) -> None:
        self._remove(self.get(collection, entity_id, sub_id), "deleted")

    def end(self, sub: Subscription) -> None:
        """A subscription whose resource finished (a goal, said by its sampler): it ends as an expiry does."""
        if self.subs.get(sub.id) is sub:
            self._remove(sub, "expired")

    # ---- registry -------------------------------------------------------------------------
    def _add(self, sub: Subscription) -> None:
        self.subs[sub.id] = sub
        self._records[sub.id] = sub.record()
        self.version += 1
        self.per_client.take(sub.client)
        self._watch(sub)
        self._arm_expiry(sub)
        self.stats.active_subscriptions = len(self.subs)

    def _remove(self, sub: Subscription, event: str) -> None:
        if self.subs.pop(sub.id, None) is None:
            return
        self._records.pop(sub.id, None)
        self.version += 1
        self.per_client.give(sub.client)
        self._unwatch(sub)
        timer = self._expiry.pop(sub.id, None)
        if timer is not None:
            timer.cancel()
        self.stats.active_subscriptions = len(self.subs)
        self._control(sub, event)
        self._save()

    def _arm_expiry(self, sub: Subscription) -> None:
        old = self._expiry.pop(sub.id, None)
        if old is not None:
            old.cancel()
        delay = max(0.0, sub.deadline - time.monotonic())
        self._expiry[sub.id] = self.executor.call_later(delay, lambda: self._expire(sub))

    def _expire(self, sub: Subscription) -> None:
        if self.subs.get(sub.id) is not sub:
            return
        if sub.deadline > time.monotonic() + 0.001:  # woken early: arm again (never left unarmed)
            self._arm_expiry(sub)
            return
        self.stats.subscriptions_expired += 1
        self._remove(sub, "expired")

    def _watch(self, sub: Subscription) -> None:
        self.samplers.get(sub.kind).watch(sub, lambda: self.end(sub))

    def _unwatch(self, sub: Subscription) -> None:
        self.samplers.get(sub.kind).unwatch(sub)

    def _control(self, sub: Subscription, event: str) -> None:
        self.events.send([events.CONTROL_KEY + sub.id.encode(), protocol.pack({
            "event": event, "id": sub.id, "key": sub.key, "interval": sub.interval,
            "expires_in": max(0.0, sub.deadline - time.monotonic())})])
