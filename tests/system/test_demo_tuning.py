"""The demo robot's parameters (demo/tuning.py) through the gateway: the README's configurations examples."""

from __future__ import annotations

import sys
import time

import requests

from common.harness.gateway import Gateway
from common.harness.procs import Proc, poll_until
from tests.support.rospub import RosNode

BASE = "/apps/temp_sensor/configurations"


def count_for(probe: RosNode, seconds: float) -> int:
    before = len(probe.echoed())
    time.sleep(seconds)
    return len(probe.echoed()) - before


def test_demo_parameters_and_a_rate_that_really_changes():
    robot = Proc([sys.executable, "-m", "demo.robot"], name="demo robot")
    gw = probe = None
    try:
        robot.wait_line(lambda line: line.startswith("demo robot running"), 30)
        gw = Gateway("--allow-configurations", "--log-level", "warning")
        poll_until(lambda: gw.get(BASE + "/publish_rate").status_code == 200, 20, message="publish_rate")
        rate = gw.get(BASE + "/publish_rate").json()
        assert rate["data"] == 10.0
        assert rate["x-medkit"]["parameter"]["floating_point_range"]["to_value"] == 50.0
        probe = RosNode({"node": "rate_probe", "subscribe": [
            {"topic": "/powertrain/engine/temperature", "type": "sensor_msgs/msg/Temperature", "echo": True}]})
        poll_until(lambda: probe.echoed(), 20, message="the probe's first message")
        slow = count_for(probe, 2.0)
        r = requests.put(gw.api + BASE + "/publish_rate", json={"data": 40.0}, timeout=10)
        assert r.status_code == 200 and r.json()["data"] == 40.0
        fast = count_for(probe, 2.0)
        assert fast > 2 * slow, (slow, fast)  # 10 Hz -> 40 Hz, with room for a loaded machine
        r = requests.put(gw.api + BASE + "/sensor_id", json={"data": "other"}, timeout=10)
        assert r.status_code == 403 and r.json()["vendor_code"] == "x-medkit-ros2-parameter-read-only"
        r = requests.put(gw.api + BASE + "/filter_window", json={"data": 50}, timeout=10)
        assert r.status_code == 400 and "filter_window" in r.json()["parameters"]["details"]
        assert requests.delete(gw.api + BASE, timeout=10).status_code == 204
        assert gw.get(BASE + "/publish_rate").json()["data"] == 10.0
    finally:
        for proc in (probe, gw, robot):
            if proc is not None:
                proc.stop()
