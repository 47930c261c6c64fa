"""``make run``'s demo robot writes /rosout at several levels, and the gateway serves it as logs (issue 22);
Ctrl-C ends the launcher with exit code 0."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile

import requests

from common.harness.procs import REPO, free_port, poll_until


def test_the_demo_robots_logs_come_at_several_levels():
    port = free_port()
    api = f"http://127.0.0.1:{port}/api/v1"
    proc = subprocess.Popen([sys.executable, "-m", "demo.run", "--bind", f"127.0.0.1:{port}",
                             "--var", tempfile.mkdtemp(prefix="sovd-demo-")],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    try:
        def levels():
            host = requests.get(api + "/components", timeout=2).json()["items"][0]["id"]
            items = requests.get(f"{api}/components/{host}/logs", timeout=5).json()["items"]
            seen = {i["severity"] for i in items}
            return items if {"debug", "error"} <= seen and seen & {"info", "warning"} else None

        items = poll_until(levels, 60, interval=0.5, message="demo log lines at debug, info or warning, and error")
        nodes = {i["context"]["node"] for i in items}
        assert {"chassis.brakes.pressure_sensor", "chassis.odometry"} <= nodes, nodes
        engine = requests.get(f"{api}/apps/temp_sensor/logs", timeout=5).json()["items"]
        assert engine and all(i["context"]["node"] == "powertrain.engine.temp_sensor" for i in engine)
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            out, _ = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate(timeout=10)
            raise
    assert proc.returncode == 0, out[-3000:]   # the launcher's own exit on Ctrl-C
