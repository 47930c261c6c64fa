"""Cyclic subscriptions on an action goal and on a parameter: the stream registry's feeds.

A subscription on ``operations/{op_id}/executions/{exec_id}`` (kind
``execution``) or on ``configurations/{param_id}`` (kind ``parameter``) is kept
by the stream registry (``rosworker/subscriptions/registry.py``) like one on a topic: the same
caps, expiry, updates, restart state and control events.  Its frames are its
own: one timer per subscription at its interval, and one frame per tick under
its own key (``d|<interval>|<kind>|<subscription id>|``), meta ``{"ts", "kind",
"last"?}`` and the JSON of what the ROS worker knows of the resource, or meta
``{"ts", "kind", "error"}``.  The HTTP side makes of it the body a GET of the
resource answers (``app/feeds.py``).

Executions: the goal's status and latest feedback as the action client keeps
them (no call to the server per tick).  Once the goal is terminal the frame
carries its result and ``last`` (the HTTP side ends the stream after it); each
tick repeats that frame for ``FINISHED_LINGER`` seconds, so that a stream
opened just after the goal finished still gets it, and then the subscription
ends (an ``expired`` control event).  A goal the gateway no longer knows (it
was forgotten after ``goal_retention``) ends the stream with an error frame.

Parameters: one read (get and describe, deadline ``parameter_service_timeout``,
through the pooled parameter clients) when the subscription starts and every
``RESYNC`` seconds after; between reads the value follows ``/parameter_events``
(the parameter clients' one subscription, drained at each tick), so that a
change made by another client is framed at the next tick without a call to the
node.  A parameter deleted, or a read that fails, gives error frames until a
later read or event brings a value back.
"""

from __future__ import annotations

import json
import time
from typing import Any

from ipc import events
from ipc.errors import IpcError

from ..core.executor import RosExecutor, Timer
from .clients import type_name, value_json

FINISHED_LINGER = 5.0  # seconds a finished goal's last frame is repeated before its subscription ends
RESYNC = 10.0          # seconds between two reads of a streamed parameter (events carry the changes between)
KINDS = ("execution", "parameter")


def _dumps(value: Any) -> bytes:
    return json.dumps(value, separators=(",", ":"), allow_nan=False).encode()


class _Feed:
    __slots__ = ("sub", "timer", "body", "error", "reading", "read_at", "touched", "finished_at")

    def __init__(self, sub: Any):
        self.sub = sub
        self.timer: Timer | None = None
        self.body: dict[str, Any] | None = None   # a parameter: the param_get answer, kept current
        self.error: IpcError | None = None
        self.reading = False
        self.read_at = 0.0
        self.touched = False                        # an event changed the value while a read was out
        self.finished_at: float | None = None       # an execution: when its last frame was first sent


class Feeds:
    """The ticks of the registry's ``execution`` and ``parameter`` subscriptions (ROS thread only)."""

    def __init__(self, registry: Any, executor: RosExecutor, actions: Any, parameters: Any):
        self.registry = registry
        self.executor = executor
        self.actions = actions
        self.parameters = parameters
        self.feeds: dict[str, _Feed] = {}
        self._by_node: dict[str, dict[str, _Feed]] = {}   # parameter feeds by node fqn
        parameters.listeners.append(self._event)

    # ---- the registry's hooks ---------------------------------------------------------------
    def check(self, sub: Any) -> None:
        """Refuse a subscription whose target is malformed or (an execution) unknown."""
        target = sub.target if isinstance(sub.target, dict) else {}
        if len(target) > 8 or any(not isinstance(k, str) or not (v is None or isinstance(v, str) and len(v) <= 4096)
                                  for k, v in target.items()):
            raise IpcError("bad-request", "target: expected at most 8 strings of up to 4096 characters")
        if sub.kind == "execution":
            goal = target.get("goal")
            if not isinstance(goal, str) or not goal:
                raise IpcError("bad-request", "target.goal: expected an execution id")
            self.actions.get(goal)
        elif sub.kind == "parameter":
            for name in ("node", "name", "id"):
                if not isinstance(target.get(name), str) or not target[name]:
                    raise IpcError("bad-request", f"target.{name}: expected a string")
        else:
            raise IpcError("bad-request", "kind: expected 'data', 'execution' or 'parameter'")

    def watch(self, sub: Any) -> None:
        feed = _Feed(sub)
        self.feeds[sub.id] = feed
        if sub.kind == "parameter":
            self._by_node.setdefault(sub.target["node"], {})[sub.id] = feed
            self._read(feed)
        self._arm(feed, 0.0)

    def unwatch(self, sub: Any) -> None:
        feed = self.feeds.pop(sub.id, None)
        if feed is None:
            return
        if feed.timer is not None:
            feed.timer.cancel()
        if sub.kind == "parameter":
            node = self._by_node.get(sub.target["node"], {})
            node.pop(sub.id, None)
            if not node:
                self._by_node.pop(sub.target["node"], None)

    # ---- ticks ------------------------------------------------------------------------------
    def _arm(self, feed: _Feed, delay: float) -> None:
        feed.timer = self.executor.call_later(delay, lambda: self._tick(feed))

    def _tick(self, feed: _Feed) -> None:
        if self.feeds.get(feed.sub.id) is not feed:
            return
        self._arm(feed, events.INTERVALS[feed.sub.interval])
        what = self._execution if feed.sub.kind == "execution" else self._parameter
        self.executor.guarded(f"the {feed.sub.kind} feed of {feed.sub.id}", what, feed)

    def _meta(self, feed: _Feed, **extra: Any) -> dict[str, Any]:
        return {"ts": time.time_ns(), "kind": feed.sub.kind, **extra}

    def _execution(self, feed: _Feed) -> None:
        sub = feed.sub
        try:
            goal = self.actions.get(sub.target["goal"])
        except IpcError as exc:
            self.registry.publish(sub.key, self._meta(feed, error=exc.to_wire(), last=True))
            self.registry.end(sub)
            return
        if not goal.done:
            self.registry.publish(sub.key, self._meta(feed), _dumps(goal.wire()))
            return
        self.registry.publish(sub.key, self._meta(feed, last=True), _dumps(goal.wire()))
        now = time.monotonic()
        if feed.finished_at is None:
            feed.finished_at = now
        elif now - feed.finished_at >= FINISHED_LINGER:
            self.registry.end(sub)

    def _parameter(self, feed: _Feed) -> None:
        self.parameters.drain_events()
        if not feed.reading and time.monotonic() - feed.read_at >= RESYNC:
            self._read(feed)
        sub = feed.sub
        if feed.error is not None:
            self.registry.publish(sub.key, self._meta(feed, error=feed.error.to_wire()))
        elif feed.body is not None:
            self.registry.publish(sub.key, self._meta(feed), _dumps({"parameter": feed.body, **sub.target}))

    # ---- parameters -------------------------------------------------------------------------
    def _read(self, feed: _Feed) -> None:
        """A get and describe of the parameter (the parameter clients' deadline applies)."""
        feed.reading = True
        feed.touched = False
        feed.read_at = time.monotonic()
        node, name = feed.sub.target["node"], feed.sub.target["name"]

        def done(result: Any) -> None:
            feed.reading = False
            if self.feeds.get(feed.sub.id) is not feed:
                return
            if isinstance(result, BaseException):
                if not feed.touched:  # an event since the read started is newer than its failure
                    feed.body = None
                    feed.error = result if isinstance(result, IpcError) else IpcError("internal", str(result))
                return
            if feed.touched and feed.body is not None:  # an event since the read started is newer
                result = {**result, "value": feed.body.get("value"), "type": feed.body.get("type")}
            feed.body = result
            feed.error = None

        self.parameters.run(node, self.parameters.op_get(node, name), done)

    def _event(self, event: Any) -> None:
        """A /parameter_events message: the streamed parameters of its node follow it."""
        feeds = self._by_node.get(event.node)
        if not feeds:
            return
        for feed in feeds.values():
            name = feed.sub.target["name"]
            for p in (*event.new_parameters, *event.changed_parameters):
                if p.name == name:
                    feed.body = {**(feed.body or {"name": name}), "value": value_json(p.value),
                                 "type": type_name(p.value)}
                    feed.error = None
                    feed.touched = True
            for p in event.deleted_parameters:
                if p.name == name:
                    feed.body = None
                    feed.error = IpcError("no-such-parameter", f"Parameter not found: {name}", {"name": name})
                    feed.touched = True
