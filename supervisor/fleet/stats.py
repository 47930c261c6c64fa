"""The link's counters (declared in ``ipc/counters.py``, section ``fleet``) and its ``stats`` answer.

Counted from Zenoh's callback threads, the query pool and the IPC threads alike: :meth:`add` takes a
lock.  ``stats`` (on the link's control socket, ``ipc/server.py``'s :class:`~ipc.server.ControlServer`)
answers the supervisor's health check and the HTTP workers' ``/health`` and ``/metrics``: the
``fleet`` section, the per-robot maps (``fleet_robots``, the fleet gateway's) and an ``executor``
section shaped like the ROS worker's, so the supervisor watches either process the same way.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from ipc import counters


class LinkStats:
    def __init__(self, cfg: Any):
        self._lock = threading.Lock()
        self._values: dict[str, Any] = counters.health_defaults("fleet", cfg)
        self.ipc_dropped_frames = 0
        self.per_robot: Callable[[], dict[str, dict[str, Any]]] = dict
        self.session_open: Callable[[], bool] = lambda: False
        self.session_attempts: Callable[[], int] = lambda: 0

    def add(self, name: str, n: int = 1) -> None:
        with self._lock:
            self._values[name] += n

    def set(self, name: str, value: Any) -> None:
        with self._lock:
            self._values[name] = value

    def get(self, name: str) -> Any:
        return self._values[name]

    def check_watchdog(self) -> None:
        """The ROS worker's control thread checks its executor here; the link has none to check."""

    def snapshot(self) -> dict[str, Any]:
        with self._lock:
            fleet = dict(self._values)
        fleet["session_open"] = bool(self.session_open())
        fleet["session_attempts"] = self.session_attempts()
        return {"executor": {"worker_alive": True, "degraded": False},
                "fleet": fleet, "fleet_robots": self.per_robot(),
                "details": {"ipc_dropped_frames": self.ipc_dropped_frames}}
