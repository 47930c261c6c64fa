"""The fleet gateway's faults: every robot's fault events, merged, and the faults family's rules.

The robots' events reach the fleet link over Zenoh; it takes each once, gives it a fleet-wide id and
names its robot in ``fault.x-medkit.contributors`` (``supervisor/fleet/robots.py``), and sends it on
its events channel (``supervisor/fleet/channel.py``), the ROS worker's channel in shape.  So the
stream is the faults family's: the same hub (``app/faults/hub.py``), reading the link's channel
instead of the ROS worker's, with ``Last-Event-ID`` replayed from what the link keeps.  The fleet
imports no family: the faults family offers its hub and its ``?status=`` check to every mode of the
app (``app/core/resources.py``'s ``Relayed``).
"""

from __future__ import annotations

from typing import Any

from flask import Flask

from ipc import fleet

from ..core import resources
from ..core.common import config
from . import link

NAME = "fleet faults"
FAULTS = "faults"


def setup(app: Flask) -> None:
    """The fleet gateway's fault hub (made in the HTTP worker that first opens one of its streams)."""
    resources.relays(app)[FAULTS].stream(app, NAME, link.EXTENSION, "fleet_events", fleet.events_endpoint,
                                         "fleet fault events")


def check(params: dict[str, Any] | None = None) -> None:
    """medkit's 400 for a bad ``?status=`` of a fault listing, before any robot is asked."""
    resources.relays()[FAULTS].check(params)


def response():
    """``GET /api/v1/faults/stream``: the merged stream (503 past ``max_fault_streams``)."""
    return resources.relays()[FAULTS].response(NAME, config().max_fault_streams)
