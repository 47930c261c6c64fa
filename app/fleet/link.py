"""The HTTP worker's side of the fleet link: one client per process, and what its errors answer.

Like ``app/core/rosclient.py`` for the ROS worker: nothing is made before the fork; the
:class:`~ipc.client.RosWorkerClient` of ``ipc/fleet.py``'s endpoint is made on first use in the
process that uses it.  Every call has a deadline; a link that does not answer is a 503 with
``x-medkit-fleet-link-unavailable`` (the supervisor restarts it), never a hung worker.
"""

from __future__ import annotations

import functools
from typing import Any

from flask import Flask, current_app

from common.process import PerProcess
from ipc import fleet
from ipc.client import RosWorkerClient
from ipc.errors import IpcError

from ..core import requestid
from ..core.errors import ApiError

EXTENSION = "sovd_fleet_link"
STATS_TIMEOUT_S = 0.3
LINK_DOWN = ("unavailable", "shutdown", "backpressure")


class FleetLink:
    def __init__(self, runtime_dir: str, ipc_timeout: float):
        self.ipc_timeout = ipc_timeout
        self._client: PerProcess[RosWorkerClient] = PerProcess(
            functools.partial(RosWorkerClient, fleet.endpoint(runtime_dir)), RosWorkerClient.close)
        self.last_status: dict[str, Any] | None = None
        self.last_stats: dict[str, Any] | None = None

    def close(self) -> None:
        self._client.reset()

    def call(self, cmd: str, args: dict[str, Any] | None = None, timeout: float | None = None) -> dict[str, Any]:
        """One command; the link's errors as the contract's (``ApiError``)."""
        try:
            return self._client.get().call(cmd, args, self.ipc_timeout if timeout is None else timeout,
                                           request_id=requestid.current())
        except IpcError as exc:
            if exc.code in LINK_DOWN:
                raise ApiError(503, "vendor-error", f"The fleet link is not available: {exc.message}",
                               vendor_code="x-medkit-fleet-link-unavailable", retry_after=2) from None
            raise ApiError.from_ipc(exc) from None

    def stats(self, timeout: float = STATS_TIMEOUT_S) -> tuple[bool, dict[str, Any] | None]:
        """``(alive, stats)`` from the link's control socket: fresh, or the last known."""
        try:
            self.last_stats = self._client.get().call("stats", timeout=timeout, connect_wait=min(0.1, timeout))
            return True, self.last_stats
        except IpcError:
            return False, self.last_stats

    def status(self, timeout: float) -> tuple[bool, dict[str, Any] | None]:
        """``(alive, fleet_status)``: the robots and warnings for ``/health``, fresh or last known."""
        try:
            self.last_status = self._client.get().call("fleet_status", timeout=timeout,
                                                       connect_wait=min(0.1, timeout))
            return True, self.last_status
        except IpcError:
            return False, self.last_status


def init_app(app: Flask) -> None:
    cfg = app.config["SOVD"]
    app.extensions[EXTENSION] = FleetLink(cfg.runtime_dir, cfg.ipc_timeout)


def get() -> FleetLink:
    return current_app.extensions[EXTENSION]
