"""The fleet gateway's ``GET /api/v1/faults/stream``: every robot's fault events, merged.

The robots' events reach the fleet link over Zenoh; it takes each once, gives it a fleet-wide id and
names its robot in ``fault.x-medkit.contributors`` (``supervisor/fleet/robots.py``), and sends it on
its events channel (``supervisor/fleet/channel.py``), the ROS worker's channel in shape.  So the
stream is the faults family's (``app/faults/hub.py``): the same hub, reading the link's channel
instead of the ROS worker's, with ``Last-Event-ID`` replayed from what the link keeps.
"""

from __future__ import annotations

from typing import Any

from flask import Flask

from ipc import fleet

from ..faults import hub as faultstream
from ..sse import hub as sse
from . import link

NAME = "fleet faults"


class FleetFaultHub(faultstream.FaultHub):
    NAME = "fleet fault events"

    def endpoint(self) -> str:
        return fleet.events_endpoint(self.runtime_dir)


def setup(app: Flask) -> None:
    """The fleet gateway's fault hub (made in the HTTP worker that first opens one of its streams)."""
    cfg = app.config["SOVD"]

    def make(_app: Flask) -> FleetFaultHub:
        fleet_link = _app.extensions[link.EXTENSION]

        def replay(after: int) -> list[dict[str, Any]]:
            return fleet_link.call("fleet_events", {"after": after}, faultstream.REPLAY_TIMEOUT).get("events") or []

        return FleetFaultHub(cfg.runtime_dir, replay, sse.worker_stopping, cfg.stream_send_timeout)

    sse.register(app, NAME, make)
