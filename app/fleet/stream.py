"""The fleet gateway's ``GET /api/v1/faults/stream``: every robot's fault events, merged.

The robots' events reach the fleet link over Zenoh; it takes each once, gives it a fleet-wide id and
names its robot in ``fault.x-medkit.contributors`` (``supervisor/fleet/robots.py``), and sends it on
its events channel (``supervisor/fleet/channel.py``), the ROS worker's channel in shape.  So the
stream is ``app/faultstream.py``'s: the same hub, reading the link's channel instead of the ROS
worker's, with ``Last-Event-ID`` replayed from what the link keeps.
"""

from __future__ import annotations

from ipc import fleet

from .. import faultstream


class FleetFaultHub(faultstream.FaultHub):
    NAME = "fleet fault events"

    def endpoint(self) -> str:
        return fleet.events_endpoint(self.runtime_dir)


def hub(runtime_dir: str, send_timeout: float) -> FleetFaultHub:
    return faultstream.hub(runtime_dir, send_timeout, FleetFaultHub)
