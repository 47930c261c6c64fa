"""The fleet link as a child of the supervisor.

On the fleet gateway the link takes the ROS worker's place (``supervisor/supervisor.py`` boots,
watches and restarts it as it would the worker): :func:`fleetlink_argv`, on ``ipc/fleet.py``'s endpoint.

On a robot it is one more child, :class:`LinkChild`: started once the gateway answers HTTP (the
link reaches it over the loopback), restarted with a backoff (``BACKOFF_BASE`` doubling up to
``BACKOFF_MAX`` seconds) whenever it dies, and never a reason to stop the gateway: a robot off the
fleet goes on serving its own API.  A link that exits 2 (bad settings) is not restarted.  It is
stopped first at shutdown, so the fleet sees the robot leave before its gateway stops answering.
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import time
from collections.abc import Callable

from ..children import Child

log = logging.getLogger("sovd.supervisor.fleet")

BACKOFF_BASE = 0.5
BACKOFF_MAX = 30.0
STABLE_AFTER = 60.0     # a link that ran this long starts the backoff again from the base
STOP_TIMEOUT = 4.0      # the link undeclares and closes its session; then SIGKILL
EXIT_CONFIG = 2


def fleetlink_argv(runtime_dir: str) -> list[str]:
    script = os.path.join(os.path.dirname(sys.executable), "sovd-fleetlink")
    if os.access(script, os.X_OK):
        return [sys.executable, script, "--runtime-dir", runtime_dir]
    return [sys.executable, "-m", "supervisor.fleet.main", "--runtime-dir", runtime_dir]


class LinkChild:
    def __init__(self, runtime_dir: str, make_env: Callable[[], dict[str, str]]):
        self.runtime_dir = runtime_dir
        self.make_env = make_env
        self.child: Child | None = None
        self.started_at = 0.0
        self.next_step: float | None = None   # when step() has something to do (a restart)
        self.restarts = 0
        self._delay = BACKOFF_BASE
        self._restart_at: float | None = None
        self._given_up = False

    def start(self) -> None:
        self.child = Child("fleet link", fleetlink_argv(self.runtime_dir), self.make_env(), signal.SIGTERM)
        self.child.start()
        self.started_at = time.monotonic()
        self.next_step = time.monotonic() + 1.0
        log.info("fleet link pid %d started", self.child.pid)

    def step(self, now: float) -> None:
        """Look at the link (the supervisor's loop): restart a dead one once its backoff has passed."""
        if self.child is None or self._given_up:
            return
        if self.child.alive():
            self.next_step = now + 1.0
            return
        if self._restart_at is None:   # found dead just now
            how = self.child.describe_exit()
            if self.child.returncode == EXIT_CONFIG:
                log.error("fleet link pid %d %s: its settings are wrong (see its message above); the gateway "
                          "goes on without the fleet", self.child.pid, how)
                self._given_up = True
                self.next_step = None
                return
            if now - self.started_at >= STABLE_AFTER:
                self._delay = BACKOFF_BASE
            log.warning("fleet link pid %d %s; restarting it in %g s", self.child.pid, how, self._delay)
            self._restart_at = self.next_step = now + self._delay
            self._delay = min(BACKOFF_MAX, self._delay * 2)
        elif now >= self._restart_at:
            self._restart_at = None
            self.restarts += 1
            self.start()

    def stop(self, stop_child: Callable[[Child, int, float], None]) -> None:
        if self.child is not None:
            stop_child(self.child, signal.SIGTERM, STOP_TIMEOUT)
        self.next_step = None
