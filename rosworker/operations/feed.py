"""The ``execution`` sampler: a cyclic subscription on an action goal (``…/operations/{op}/executions/{id}``).

Registered with the core's samplers (``core/samplers.py``); the subscriptions
family keeps the subscription (caps, expiry, updates, restart state), this
frames it: one timer per subscription at its interval, one frame per tick under
its own key (``d|<interval>|execution|<subscription id>|``), meta ``{"ts",
"kind", "last"?}`` and the goal's status and latest feedback as the action
client keeps them (no call to the server per tick), or meta ``{"ts", "kind",
"error"}``.  The HTTP side makes of it the body a GET of the execution answers.

Once the goal is terminal the frame carries its result and ``last`` (the HTTP
side ends the stream after it); each tick repeats that frame for
``FINISHED_LINGER`` seconds, so that a stream opened just after the goal
finished still gets it, and then the subscription ends (an ``expired`` control
event).  A goal the gateway no longer knows (forgotten after
``goal_retention``) ends the stream with an error frame.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from typing import Any

from ipc.errors import IpcError

from ..core.samplers import Feed, TimedSampler
from .actions import ActionClients

FINISHED_LINGER = 5.0  # seconds a finished goal's last frame is repeated before its subscription ends


def dumps(value: Any) -> bytes:
    return json.dumps(value, separators=(",", ":"), allow_nan=False).encode()


class _Execution(Feed):
    def __init__(self, sub: Any, end: Callable[[], None]):
        super().__init__(sub, end)
        self.finished_at: float | None = None   # when its last frame was first sent


class ExecutionFeed(TimedSampler):
    kind = "execution"

    def __init__(self, core: Any, actions: ActionClients):
        super().__init__(core)
        self.actions = actions

    def make(self, sub: Any, end: Callable[[], None]) -> Feed:
        return _Execution(sub, end)

    def check(self, sub: Any) -> None:
        """Refuse a subscription whose goal is malformed or unknown."""
        goal = sub.target.get("goal")
        if not isinstance(goal, str) or not goal:
            raise IpcError("bad-request", "target.goal: expected an execution id")
        self.actions.get(goal)

    def frame(self, feed: _Execution) -> None:
        try:
            goal = self.actions.get(feed.sub.target["goal"])
        except IpcError as exc:
            self.publish(feed, error=exc.to_wire(), last=True)
            feed.end()
            return
        if not goal.done:
            self.publish(feed, dumps(goal.wire()))
            return
        self.publish(feed, dumps(goal.wire()), last=True)
        now = time.monotonic()
        if feed.finished_at is None:
            feed.finished_at = now
        elif now - feed.finished_at >= FINISHED_LINGER:
            feed.end()
