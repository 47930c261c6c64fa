"""``make run``'s launcher (demo/run.py): live demo data, and Ctrl-C stops everything in order."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile

import psutil
import requests

from tests.support.procs import REPO, free_port, poll_until


def test_demo_serves_live_data_and_ctrl_c_stops_everything_in_order():
    port = free_port()
    runtime_dir = tempfile.mkdtemp(prefix="sovd-demo-")
    api = f"http://127.0.0.1:{port}/api/v1"
    # A session of its own, so that the test can do what a terminal does on Ctrl-C:
    # SIGINT to the whole foreground process group.
    proc = subprocess.Popen([sys.executable, "-m", "demo.run", "--bind", f"127.0.0.1:{port}",
                             "--runtime-dir", runtime_dir],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    descendants: list[psutil.Process] = []
    try:
        def live():
            host = requests.get(api + "/components", timeout=2).json()["items"][0]["id"]
            body = requests.get(f"{api}/components/{host}/data/powertrain/engine/temperature", timeout=5).json()
            return body if body["x-medkit"]["status"] == "data" else None

        body = poll_until(live, 60, interval=0.2, message="live demo data")
        assert isinstance(body["data"]["temperature"], float)
        descendants = psutil.Process(proc.pid).children(recursive=True)
        names = " ".join(" ".join(p.cmdline()) for p in descendants)
        assert "demo.robot" in names and "sovd-rosworker" in names and "gunicorn" in names
        os.killpg(proc.pid, signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate(timeout=10)
    assert proc.returncode == 0, out[-3000:]
    assert "stopped (exit code 0)" in out, out[-3000:]
    assert "second stop signal" not in out and "SIGKILL" not in out, out[-3000:]
    for p in descendants:
        assert not p.is_running() or p.status() == psutil.STATUS_ZOMBIE, f"left behind: {p.cmdline()}"
