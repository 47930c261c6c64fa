"""The demo robot's battery and wheel (demo/battery.py, demo/robot.py): what they report over time."""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticStatus
from sensor_msgs.msg import BatteryState

from demo import battery, robot


def test_the_battery_warns_soon_after_the_start_below_the_threshold_and_recovers():
    steps = [battery.PERIOD * i / 720 for i in range(1441)]   # two cycles
    charges = [battery.charge(t) for t in steps]
    assert 0.19 < min(charges) < battery.LOW < 0.94 < max(charges) <= 0.95 + 1e-9
    first_low = next(t for t in steps if battery.status(t).level == DiagnosticStatus.WARN)
    assert battery.LOW_AFTER - 1 <= first_low <= battery.LOW_AFTER + 1
    for t in steps:
        s = battery.status(t)
        assert (s.level == DiagnosticStatus.WARN) == (battery.charge(t) < battery.LOW)
        assert s.name == "battery_monitor: Battery"
    assert any(battery.status(t).level == DiagnosticStatus.OK for t in steps if t > first_low)


class Logger:
    def __init__(self):
        self.lines = []

    def info(self, text):
        self.lines.append(("info", text))

    def warning(self, text):
        self.lines.append(("warning", text))


def test_the_battery_says_one_charge_everywhere():
    """BatteryState, the log line and the /diagnostics status tell the same charge at any moment."""
    for t in (0.0, 10.0, 23.0, 60.0, 100.0, 200.0):
        msg = BatteryState()
        battery.fill(msg, t)
        logger = Logger()
        battery.log_line(logger, t)
        status = {kv.key: kv.value for kv in battery.status(t).values}
        shown = f"{100 * msg.percentage:.0f}"
        assert status["charge_percent"] == shown
        (level, text), = logger.lines
        assert text.endswith(f"{shown} %") and (level == "warning") == (msg.percentage < battery.LOW)


def test_the_engine_crosses_80_degrees_and_the_wheel_slips_every_cycle():
    temps = [robot.engine_temperature(t / 10) for t in range(0, 601)]
    assert 81 < temps[0] < 83 and temps[1] > temps[0]          # 82 °C and warming at the start
    ups = [i for i in range(1, len(temps)) if temps[i - 1] <= 80 < temps[i]]
    assert len(ups) == 2 and all(i / 10 < 30 * k for k, i in enumerate(ups, 1))
    assert any(t > robot.ENGINE_HOT for t in temps[:100])     # a warning within 10 s
    slips = [t / 10 for t in range(0, 601) if robot.slipping(t / 10)]
    assert slips and min(slips) == robot.SLIP_AFTER and max(slips) < 60
