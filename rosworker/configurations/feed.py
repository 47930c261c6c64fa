"""The ``parameter`` sampler: a cyclic subscription on a parameter (``…/configurations/{param_id}``).

Registered with the core's samplers (``core/samplers.py``); the subscriptions
family keeps the subscription (caps, expiry, updates, restart state), this
frames it: one timer per subscription at its interval, one frame per tick under
its own key (``d|<interval>|parameter|<subscription id>|``), meta ``{"ts",
"kind"}`` and the JSON of what the ROS worker knows of the parameter, or meta
``{"ts", "kind", "error"}``.  The HTTP side makes of it the body a GET of the
parameter answers.

One read (get and describe, deadline ``parameter_service_timeout``, through the
pooled parameter clients) when the subscription starts and every ``RESYNC``
seconds after; between reads the value follows ``/parameter_events`` (the
subscription of ``defaults.py``, drained at each tick), so that a change
made by another client is framed at the next tick without a call to the node.
A parameter deleted, or a read that fails, gives error frames until a later
read or event brings a value back.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from typing import Any

from ipc.errors import IpcError

from ..core.samplers import Feed, TimedSampler
from .clients import ParameterClients
from .commands import ParameterCommands
from .defaults import Defaults
from .values import type_name, value_json

RESYNC = 10.0          # seconds between two reads of a streamed parameter (events carry the changes between)


def _dumps(value: Any) -> bytes:
    return json.dumps(value, separators=(",", ":"), allow_nan=False).encode()


class _Parameter(Feed):
    def __init__(self, sub: Any, end: Callable[[], None]):
        super().__init__(sub, end)
        self.body: dict[str, Any] | None = None   # the param_get answer, kept current
        self.error: IpcError | None = None
        self.reading = False
        self.read_at = 0.0
        self.touched = False                        # an event changed the value while a read was out


class ParameterFeed(TimedSampler):
    kind = "parameter"

    def __init__(self, core: Any, parameters: ParameterClients, defaults: Defaults,
                 commands: ParameterCommands):
        super().__init__(core)
        self.parameters = parameters
        self.defaults = defaults
        self.commands = commands
        self._by_node: dict[str, dict[str, _Parameter]] = {}   # feeds by node fqn
        defaults.listeners.append(self._event)

    def check(self, sub: Any) -> None:
        for name in ("node", "name", "id"):
            if not isinstance(sub.target.get(name), str) or not sub.target[name]:
                raise IpcError("bad-request", f"target.{name}: expected a string")

    def make(self, sub: Any, end: Callable[[], None]) -> Feed:
        feed = _Parameter(sub, end)
        self._by_node.setdefault(sub.target["node"], {})[sub.id] = feed
        return feed

    def watch(self, sub: Any, end: Callable[[], None]) -> None:
        super().watch(sub, end)
        self._read(self.feeds[sub.id])  # its first read, now (its first tick comes next round)

    def dropped(self, feed: Feed) -> None:
        node = self._by_node.get(feed.sub.target["node"], {})
        node.pop(feed.sub.id, None)
        if not node:
            self._by_node.pop(feed.sub.target["node"], None)

    def frame(self, feed: _Parameter) -> None:
        self.defaults.drain()
        if not feed.reading and time.monotonic() - feed.read_at >= RESYNC:
            self._read(feed)
        if feed.error is not None:
            self.publish(feed, error=feed.error.to_wire())
        elif feed.body is not None:
            self.publish(feed, _dumps({"parameter": feed.body, **feed.sub.target}))

    def _read(self, feed: _Parameter) -> None:
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

        self.parameters.run(node, self.commands.op_get(node, name), done)

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
