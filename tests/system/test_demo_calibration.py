"""The demo robot's calibrate service and long_calibration action, through the real gateway, as the
README's curl lines use them."""

from __future__ import annotations

import sys

import requests

from common.harness.gateway import Gateway
from common.harness.procs import Proc, poll_until


def test_demo_calibration_service_and_action():
    robot = Proc([sys.executable, "-m", "demo.robot"], name="demo robot")
    gateway = None
    try:
        robot.wait_line(lambda line: line.startswith("demo robot running"), 30)
        gateway = Gateway("--allow-operations")
        ops = poll_until(lambda: {i["id"] for i in gateway.get("/apps/calibration/operations").json()
                                  .get("items", [])} == {"calibrate", "long_calibration"} or None, 20,
                         message="the demo's operations")
        assert ops
        base = gateway.api + "/apps/calibration/operations"
        r = requests.post(base + "/calibrate/executions", json={}, timeout=15)
        assert r.status_code == 200 and r.json()["parameters"]["success"] is True
        r = requests.post(base + "/long_calibration/executions", json={"parameters": {"order": 3}}, timeout=15)
        assert r.status_code == 202, r.text
        done = poll_until(lambda: (lambda b: b if b["status"] == "completed" else None)(
            requests.get(gateway.url + r.headers["Location"], timeout=10).json()), 20, message="calibrated")
        assert done["parameters"]["sequence"] == [0, 1, 1, 2]
        # The sensors kept publishing while the action ran (one executor, the steps wait on timers).
        assert gateway.get("/apps/temp_sensor/data/powertrain/engine/temperature").status_code == 200
    finally:
        if gateway is not None:
            gateway.stop()
        robot.stop()
