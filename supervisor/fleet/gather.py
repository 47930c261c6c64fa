"""One Zenoh query to the robots of the fleet, and its replies: at most one a robot, until every robot
expected answered or the query ends (its timeout).

:class:`Gather` launches the query (a robot's own key, or the wildcard ``sovd/*/...`` for everybody) and
keeps each robot's first reply with how long it took; an error reply names no robot, so that robot
counts as not answered.  Its ``on_done`` runs on a Zenoh thread once every query launched ended.
:class:`NotAnswered` is what a forwarded request raises when its robot was away or silent.
"""

from __future__ import annotations

import threading
import time

from ipc import fleet as wire


class NotAnswered(Exception):
    """A forwarded request had no answer: ``reason`` is ``offline`` or ``timeout``."""

    def __init__(self, robot: str, reason: str, seconds: float):
        super().__init__(reason)
        self.robot, self.reason, self.seconds = robot, reason, seconds


class Gather:
    """The replies of one query, by robot, until every robot expected answered or the query ends."""

    def __init__(self, expected: set[str] | None, on_done=None):
        self.expected = expected            # None: anyone (a wildcard query)
        self.on_done = on_done              # called once, on a Zenoh thread, when every query ended
        self.replies: dict[str, tuple[float, bytes]] = {}
        self.errors: dict[str, str] = {}
        self.done = threading.Event()
        self.started = time.monotonic()
        self._open = 0
        self._lock = threading.Lock()

    def launch(self, session, selector: str, payload: bytes, timeout: float) -> None:
        import zenoh

        with self._lock:
            self._open += 1
        session.get(selector, handler=zenoh.handlers.Callback(self._reply, self._finished), payload=payload,
                    timeout=timeout, consolidation=zenoh.ConsolidationMode.NONE)

    def _reply(self, reply) -> None:
        now = time.monotonic()
        if reply.ok is None:
            return  # an error reply names no robot; the robot counts as not answered
        parsed = wire.parse_key(str(reply.ok.key_expr))
        if parsed is None:
            return
        robot = parsed[0]
        if self.expected is not None and robot not in self.expected:
            return
        with self._lock:
            if robot not in self.replies:
                self.replies[robot] = (now - self.started, reply.ok.payload.to_bytes())
            complete = self.expected is not None and self.expected <= self.replies.keys()
        if complete:
            self.done.set()

    def _finished(self) -> None:
        with self._lock:
            self._open -= 1
            last = self._open <= 0
        if last:
            self.done.set()
            if self.on_done is not None:
                self.on_done(self)

    def wait(self, timeout: float) -> None:
        self.done.wait(max(0.0, timeout))
