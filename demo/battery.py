"""The demo battery's ``/diagnostics``: WARN while its charge is low, OK again once it recharged.

The charge runs a cycle of ``PERIOD`` seconds between 10 % and 100 %; below ``LOW`` it reports
``battery_monitor: Battery`` at WARN ("charge low"), so that a gateway started beside the demo
shows a fault being confirmed, then healing, and again on the next cycle (README "Faults").
The status name starts with the node's name, as ``diagnostic_updater`` names its statuses: the
gateway reports the fault under the app ``battery_monitor``.
"""

from __future__ import annotations

import math
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

PERIOD = 90.0   # seconds of one discharge and recharge
LOW = 0.25      # charge below which the battery warns
RATE = 1.0      # reports per second


def charge(t: float) -> float:
    """The demo charge at monotonic time ``t``: 0.10 … 1.00."""
    return 0.55 + 0.45 * math.cos(2 * math.pi * t / PERIOD)


def status(t: float) -> DiagnosticStatus:
    level = charge(t)
    low = level < LOW
    return DiagnosticStatus(
        level=DiagnosticStatus.WARN if low else DiagnosticStatus.OK, name="battery_monitor: Battery",
        message="charge low" if low else "ok", hardware_id="battery-pack-1",
        values=[KeyValue(key="charge_percent", value=f"{100 * level:.0f}"),
                KeyValue(key="low_threshold_percent", value=f"{100 * LOW:.0f}")])


def add_diagnostics(node) -> None:
    """Publish the battery's status on ``/diagnostics`` from ``node`` (the demo's battery monitor)."""
    pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)

    def tick() -> None:
        msg = DiagnosticArray()
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.status = [status(time.monotonic())]
        pub.publish(msg)

    node.create_timer(1.0 / RATE, tick)
