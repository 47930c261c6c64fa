"""``make bench`` end to end in its tiny mode: every case runs and lands in the JSON.

The figures of a quick run are not checked (timing belongs to the bench, not
to test assertions); only that the harness starts its publishers and a real
gateway, measures every case, writes a well-formed result and cleans up.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from common.harness.procs import REPO

CASES = {"floor8", "floor1", "warm8", "warm1", "echo8", "echo1", "hop1", "inside", "old", "cold", "image",
         "image_b64", "idle", "memory", "streams", "fanout", "stream_image", "made_up", "sub_changes",
         "trigger",  # operations: a Trigger call against a bare rclpy client
         "param_get", "param_put", "rosout",  # configurations (bench/params.py); logs (bench/logs.py)
         "faults_cpu", "faults_confirm",  # faults (issue 22): bench/faults.py
         "fleet_faults", "fleet_hung", "fleet_fault_stream", "fleet_memory", "fleet_idle",  # bench/fleet.py
         "auth", "write_checks",  # a JWT on every warm sample, a write's lock check and audit (issue 31): bench/auth.py
         "rosbag_cpu", "rosbag_write_sample", "rosbag_download",  # recordings of faults (issue 32): bench/bulk_data.py
         "wake_idle", "triggers", "triggers_shared"}  # the ROS worker wakes on events (issue 33): bench/wakeups.py


@pytest.mark.timeout(420)
def test_quick_bench_runs_every_case_and_writes_json(tmp_path):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    # The bench claims its own ROS domain (as a test session does): let it.
    env.pop("ROS_DOMAIN_ID", None)
    env.pop("SOVD_TEST_DOMAIN_CLAIMED", None)
    proc = subprocess.run([sys.executable, "-m", "bench.run", "--quick", "--no-install", "--out", str(tmp_path)],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=400)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    files = list(tmp_path.glob("bench-*-quick.json"))
    assert len(files) == 1, proc.stdout[-2000:]
    result = json.loads(files[0].read_text())
    assert result["error"] is None
    assert result["mode"] == "quick"
    assert result["load_generator"]
    rows = {row["key"]: row for row in result["cases"]}
    assert set(rows) == CASES
    for row in rows.values():
        assert row["result"] in ("PASS", "FAIL", "report"), row
        assert row["measured"] and row["values"], row
    assert rows["warm8"]["values"]["rps"] > 0
    assert rows["floor1"]["values"]["p50_ms"] > 0
    assert rows["hop1"]["values"]["p50_ms"] > 0
    assert rows["trigger"]["values"]["gateway_p50_ms"] > 0 and rows["trigger"]["values"]["bare_p50_ms"] > 0
    assert rows["echo8"]["values"]["rps"] > 0 and rows["echo8"]["values"]["errors"] == 0  # the echo route answers
    assert rows["echo1"]["values"]["p50_ms"] > 0
    assert rows["inside"]["values"]["samples"] > 0 and rows["inside"]["values"]["us_per_sample"] > 0
    cold = rows["cold"]["values"]
    assert len(cold["samples_ms"]) + cold["misses"] == 3  # every fresh topic was read once
    assert rows["idle"]["values"]["pooled"] >= 50
    assert rows["memory"]["values"]["pooled"] > 0
    assert rows["made_up"]["values"]["active_subscriptions"] == 20  # --quick makes 20, all held while measured
    changes = rows["sub_changes"]["values"]
    assert set(changes) == {"5", "25"} and all(v["post_p50_ms"] > 0 and v["delete_p50_ms"] > 0
                                                for v in changes.values())
    # faults (issue 22): the arrays were taken, every probe fault was confirmed
    assert rows["faults_cpu"]["values"]["arrays_taken"] > 0  # the worker took /diagnostics while measured
    assert rows["faults_confirm"]["values"]["n"] == 5 and rows["faults_confirm"]["values"]["p50_ms"] > 0
    # issue 31: both gateways answered the warm sample; every write of the checked gateway was audited
    assert rows["auth"]["values"]["auth8"]["rps"] > 0 and rows["auth"]["values"]["plain8"]["rps"] > 0
    assert rows["write_checks"]["values"]["audited"] >= rows["write_checks"]["values"]["n"] > 0
    # issue 32: a recording was written while samples were taken, and downloaded
    assert rows["rosbag_write_sample"]["values"]["recordings_written"] > 0
    assert rows["rosbag_download"]["values"]["size_bytes"] > 0 and rows["rosbag_download"]["values"]["rounds"] >= 1
    # The table is printed, one line per case.
    for row in rows.values():
        assert row["case"] in proc.stdout
