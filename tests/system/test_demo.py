"""``make run``'s launcher (demo/run.py): live demo data, its own dirs and a banner that says where
everything is, the robot's lines in a file, and Ctrl-C stops everything in order."""

from __future__ import annotations

import os
import signal
import subprocess
import tempfile
import threading
from pathlib import Path

import psutil
import requests

from common.harness.procs import REPO, free_port, poll_until


def test_demo_serves_live_data_and_ctrl_c_stops_everything_in_order():
    port = free_port()
    var = Path(tempfile.mkdtemp(prefix="sovd-demo-"))
    api = f"http://127.0.0.1:{port}/api/v1"
    # A session of its own, so that the test can do what a terminal does on Ctrl-C:
    # SIGINT to the whole foreground process group.  `make run` with ARGS, as an operator starts it.
    proc = subprocess.Popen(["make", "-s", "-o", ".venv/.installed", "run", f"BIND=127.0.0.1:{port}",
                             f"ARGS=--var {var} --allow-fault-clear"],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)  # the terminal's view
    reader.start()
    descendants: list[psutil.Process] = []
    try:
        def live():
            host = requests.get(api + "/components", timeout=2).json()["items"][0]["id"]
            body = requests.get(f"{api}/components/{host}/data/powertrain/engine/temperature", timeout=5).json()
            return body if body["x-medkit"]["status"] == "data" else None

        body = poll_until(live, 60, interval=0.2, message="live demo data")
        assert isinstance(body["data"]["temperature"], float)
        # ARGS reached the gateway; it keeps its faults in the demo's own state dir.
        assert requests.get(api + "/", timeout=5).json()["capabilities"]["fault_clear"] is True
        assert (var / "state" / "faults.db").exists() and (var / "run").is_dir()
        poll_until(lambda: "brake pressure sampled" in (var / "robot.log").read_text(), 30,
                   message="the robot's ROS log lines in its log file")
        descendants = psutil.Process(proc.pid).children(recursive=True)
        names = " ".join(" ".join(p.cmdline()) for p in descendants)
        assert "demo.robot" in names and "sovd-rosworker" in names and "gunicorn" in names
        # the banner comes once the launcher's own look at /health answered (a loaded machine: later)
        poll_until(lambda: any("sovd-gateway demo is running" in line for line in lines), 30, interval=0.1,
                   message="the banner")
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
        reader.join(timeout=10)
    out = "".join(lines)
    # make passes the SIGINT on after its recipe ended (as in a terminal: "make: *** [run] Interrupt");
    # the launcher's own exit code is checked in test_demo_logs.py, which starts it without make.
    assert proc.returncode == -signal.SIGINT, out[-3000:]
    banner = out[out.index("sovd-gateway demo is running"):]
    for line in (f"dashboard    http://127.0.0.1:{port}/", f"health       http://127.0.0.1:{port}/api/v1/health",
                 f"state dir    {var}/state", f"runtime dir  {var}/run",
                 f"--runtime-dir {var}/run ping", f"robot log    {var}/robot.log"):
        assert line in banner, banner
    # The robot's ROS log lines went to its file, not to the terminal.
    assert "brake pressure sampled" not in out and "[chassis.brakes.pressure_sensor]" not in out, out[-3000:]
    assert "stopped (exit code 0)" in out, out[-3000:]
    assert "second stop signal" not in out and "SIGKILL" not in out, out[-3000:]
    for p in descendants:
        assert not p.is_running() or p.status() == psutil.STATUS_ZOMBIE, f"left behind: {p.cmdline()}"
