"""The demo battery's /diagnostics (demo/battery.py): it warns while its charge is low, and recovers."""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticStatus

from demo import battery


def test_the_battery_warns_below_the_threshold_and_recovers_within_a_period():
    steps = [battery.PERIOD * i / 360 for i in range(361)]
    levels = [battery.status(t).level for t in steps]
    charges = [battery.charge(t) for t in steps]
    assert 0.09 < min(charges) < battery.LOW < 0.99 < max(charges) <= 1.0
    assert DiagnosticStatus.WARN in levels and DiagnosticStatus.OK in levels
    for t in steps:
        s = battery.status(t)
        assert (s.level == DiagnosticStatus.WARN) == (battery.charge(t) < battery.LOW)
        assert s.name == "battery_monitor: Battery"
    warn_at = next(t for t in steps if battery.status(t).level == DiagnosticStatus.WARN)
    assert any(battery.status(t).level == DiagnosticStatus.OK for t in steps if t > warn_at)
