"""A subscription read in batches that wakes the ROS thread only when something comes.

For the family subscriptions that always have a reader (/diagnostics for the faults, /rosout for
the logs): while it is quiet it is in the waiter's wait set (``waiter.py``) and costs no wake-up;
its first message wakes the ROS thread at once, and while messages keep coming it is taken at most
every ``every`` seconds (it is out of the wait set meanwhile), so a chatty topic costs a batch per
period, not a wake-up per message.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from .executor import RosExecutor


class Batched:
    """``take()`` (returns how many it took) runs when ``sub()`` has something, at most every ``every`` s."""

    def __init__(self, executor: RosExecutor, name: str, sub: Callable[[], object], take: Callable[[], int],
                 every: float):
        self._sub = sub
        self._take = take
        self.every = every
        self.took_at = -every   # when a take last found something (monotonic)
        executor.add_poller(name, self.waitables, self.poll, self.due)

    def waitables(self) -> list:
        sub = self._sub()
        if sub is None or time.monotonic() - self.took_at < self.every:
            return []
        return [sub]

    def due(self) -> float | None:
        when = self.took_at + self.every
        return when if self._sub() is not None and when > time.monotonic() else None

    def poll(self) -> None:
        if self._sub() is not None and time.monotonic() - self.took_at >= self.every and self._take():
            self.took_at = time.monotonic()
