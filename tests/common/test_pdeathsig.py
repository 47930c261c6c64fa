"""common/pdeathsig.py: a child arms its own parent-death signal, and refuses to start without its parent.

Real processes throughout: a stand-in supervisor that starts a child and is then SIGKILLed, and the
real ``sovd-rosworker`` and gunicorn master started as if their supervisor had already died.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import psutil

from common import pdeathsig
from common.harness.procs import Proc, free_port, poll_until

BIN = Path(sys.executable).parent

# The child: arms what its environment says, reports, and records the signal it dies of.
CHILD = """
import signal, sys, time
from common import pdeathsig
def died(sig, _frame):
    open(sys.argv[1], "w").write(signal.Signals(sig).name)
    sys.exit(0)
signal.signal(signal.SIGTERM, died)
print("ARMED" if pdeathsig.arm() else "ORPHAN", flush=True)
time.sleep(60)
"""
# The stand-in supervisor: starts the child with pdeathsig.child_env(), nothing between fork and exec.
PARENT = """
import os, signal, subprocess, sys, time
from common import pdeathsig
child = subprocess.Popen([sys.executable, "-c", sys.argv[1], sys.argv[2]],
                         env={**os.environ, **pdeathsig.child_env(signal.SIGTERM)})
print(child.pid, flush=True)
time.sleep(60)
"""


def test_child_env_names_this_process_and_the_signal():
    assert pdeathsig.child_env(signal.SIGKILL) == {"SOVD_SUPERVISOR_PID": str(os.getpid()),
                                                   "SOVD_PARENT_DEATH_SIGNAL": "9"}
    assert pdeathsig.arm({}) is True  # started by hand: nothing to arm, nothing to check
    assert pdeathsig.arm({"SOVD_SUPERVISOR_PID": "not a pid"}) is True


def test_a_child_dies_of_its_signal_when_its_supervisor_is_killed(tmp_path):
    record = tmp_path / "died-of"
    parent = Proc([sys.executable, "-c", PARENT, CHILD, str(record)], name="stand-in supervisor")
    try:
        child_pid = int(parent.wait_line(lambda line: line.isdigit(), 20))
        parent.wait_line(lambda line: line == "ARMED", 20)
        os.kill(parent.pid, signal.SIGKILL)
        poll_until(record.exists, 20, message="the child to get its parent-death signal")
        assert record.read_text() == "SIGTERM"
        poll_until(lambda: not psutil.pid_exists(child_pid)
                   or psutil.Process(child_pid).status() == psutil.STATUS_ZOMBIE, 20, message="child gone")
    finally:
        parent.stop()


def test_a_child_whose_supervisor_is_already_gone_says_so(tmp_path):
    """The supervisor died between fork and the child's prctl: the child is re-parented."""
    parent = Proc([sys.executable, "-c", CHILD, str(tmp_path / "unused")],
                  env=pdeathsig.child_env(signal.SIGTERM, supervisor_pid=1), name="orphan")
    try:
        parent.wait_line(lambda line: line in ("ARMED", "ORPHAN"), 20)
        assert "ORPHAN" in parent.output
    finally:
        parent.stop()


def test_ros_worker_without_its_supervisor_does_not_start(tmp_path):
    runtime = str(tmp_path)
    worker = Proc([str(BIN / "sovd-rosworker"), "--runtime-dir", runtime],
                  env=pdeathsig.child_env(signal.SIGKILL, supervisor_pid=1), name="orphan rosworker")
    try:
        assert worker.proc.wait(timeout=30) == 1
        assert any("the supervisor that started it is gone" in line for line in worker.output)
        assert not os.path.exists(os.path.join(runtime, "rosworker.sock"))  # it never served
    finally:
        worker.stop()


# What the ROS worker has loaded when main() arms its death signal: only what importing the module
# loads (the heavy modules come inside Worker, after arming and the settings; rosworker/main.py).
LOADED_AT_ARM = """
import sys
import rosworker.main
print(",".join(m for m in ("zmq", "rclpy", "numpy", "orjson") if m in sys.modules))
"""


def test_ros_worker_arms_its_death_signal_before_loading_rclpy_or_zmq():
    out = subprocess.run([sys.executable, "-c", LOADED_AT_ARM], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"loaded by importing rosworker.main: {out.stdout.strip()}"


def test_gunicorn_master_without_its_supervisor_does_not_start(tmp_path):
    port = free_port()
    env = {"SOVD_BIND": f"127.0.0.1:{port}", "SOVD_RUNTIME_DIR": str(tmp_path), "SOVD_WORKERS": "1",
           **pdeathsig.child_env(signal.SIGTERM, supervisor_pid=1)}
    master = Proc([sys.executable, "-m", "gunicorn", "-c", "python:app.gunicorn_conf", "app.wsgi:create_app()"],
                  env=env, name="orphan gunicorn")
    try:
        assert master.proc.wait(timeout=30) == 1
        text = "\n".join(master.output)
        assert "the supervisor is gone" in text
        assert "Listening at" not in text and "Booting worker" not in text
    finally:
        master.stop()
