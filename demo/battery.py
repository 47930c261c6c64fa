"""The demo battery: one charge, shown the same way on ``/power/battery``, in the logs and in ``/diagnostics``.

The charge runs a cycle of ``PERIOD`` seconds between 20 % and 95 %, counted from the demo's start;
it first falls below ``LOW`` about ``LOW_AFTER`` seconds after the start, so that a gateway started
beside the demo shows a fault being confirmed within seconds, then healing, and again on the next
cycle (README "Faults").  Everything the battery says comes from :func:`charge`:

- ``BatteryState`` on ``/power/battery`` (2 Hz): ``percentage`` is the charge, ``voltage`` follows
  it; the temperature, current and charge in Ah are not measured (NaN, as BatteryState says);
- a log line every 3 s: "battery at 80 %", or the warning "battery low: 22 %" below ``LOW``;
- ``battery_monitor: Battery`` on ``/diagnostics`` (1 Hz): WARN "charge low" below ``LOW``, else
  OK, with the charge in percent.  The status name starts with the node's name, as
  ``diagnostic_updater`` names its statuses: the gateway reports the fault under the app
  ``battery_monitor``.
"""

from __future__ import annotations

import math

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from sensor_msgs.msg import BatteryState

PERIOD = 180.0     # seconds of one discharge and recharge
LOW = 0.25         # charge below which the battery warns
LOW_AFTER = 8.0    # seconds after the start at which the charge first falls below LOW
FULL, EMPTY = 0.95, 0.20
_MID, _SWING = (FULL + EMPTY) / 2, (FULL - EMPTY) / 2
# The lowest point comes as long after LOW_AFTER as the charge takes to fall from LOW to EMPTY.
_LOWEST_AT = LOW_AFTER + PERIOD / (2 * math.pi) * math.acos((_MID - LOW) / _SWING)
VOLTS_EMPTY, VOLTS_FULL = 21.0, 25.2


def charge(t: float) -> float:
    """The charge (0.20 … 0.95) ``t`` seconds after the demo's start."""
    return _MID - _SWING * math.cos(2 * math.pi * (t - _LOWEST_AT) / PERIOD)


def percent(t: float) -> str:
    """The charge as every message of the battery writes it: "80 %"."""
    return f"{100 * charge(t):.0f} %"


def fill(msg: BatteryState, t: float) -> None:
    level = charge(t)
    msg.percentage = level
    msg.voltage = VOLTS_EMPTY + (VOLTS_FULL - VOLTS_EMPTY) * level
    msg.temperature = msg.current = msg.charge = msg.capacity = math.nan   # not measured
    msg.design_capacity = 20.0
    msg.power_supply_status = BatteryState.POWER_SUPPLY_STATUS_DISCHARGING
    msg.present = True


def log_line(logger, t: float) -> None:
    if charge(t) < LOW:
        logger.warning(f"battery low: {percent(t)}")
    else:
        logger.info(f"battery at {percent(t)}")


def status(t: float) -> DiagnosticStatus:
    low = charge(t) < LOW
    return DiagnosticStatus(
        level=DiagnosticStatus.WARN if low else DiagnosticStatus.OK, name="battery_monitor: Battery",
        message="charge low" if low else "ok", hardware_id="battery-pack-1",
        values=[KeyValue(key="charge_percent", value=f"{100 * charge(t):.0f}"),
                KeyValue(key="low_threshold_percent", value=f"{100 * LOW:.0f}")])
