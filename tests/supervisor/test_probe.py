"""``sovd-probe`` against a real ROS worker (``sovd-rosworker`` started directly)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from common.harness.procs import REPO, Proc, poll_until
from ipc import protocol
from ipc.client import RosWorkerClient
from ipc.errors import IpcError
from tests.support.rospub import publisher

BIN = Path(sys.executable).parent
TOPIC = "/probe_test/level"


def probe(*args: str, timeout: float = 30, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / "sovd-probe"), *args], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO, env={**os.environ, **(env or {})})


@pytest.fixture(scope="module")
def level_pub():
    node = publisher("probe_level", TOPIC, "std_msgs/msg/Float32", {"data": 42.5}, rate=20)
    yield node
    node.stop()


@pytest.fixture(scope="module")
def worker(tmp_path_factory):
    runtime = str(tmp_path_factory.mktemp("probe-rt"))
    os.chmod(runtime, 0o700)
    proc = Proc([str(BIN / "sovd-rosworker"), "--runtime-dir", runtime, "--debug-commands",
                 "--watchdog-threshold", "200"], name="sovd-rosworker")
    client = RosWorkerClient.for_runtime_dir(runtime)
    try:
        poll_until(lambda: client.call("ping", timeout=1), 30, message="ROS worker ready")
        proc.runtime_dir = runtime
        yield proc
    finally:
        client.close()
        proc.stop()


def js(r: subprocess.CompletedProcess) -> dict:
    return json.loads(r.stdout)


def test_ping(worker):
    r = probe("--runtime-dir", worker.runtime_dir, "ping")
    assert r.returncode == 0, r.stderr
    assert f"ROS worker pid {worker.pid} answers" in r.stdout
    r = probe("--runtime-dir", worker.runtime_dir, "ping", "--json")
    assert r.returncode == 0
    body = js(r)
    assert body["ok"] is True and body["command"] == "ping"
    assert body["result"]["pid"] == worker.pid
    assert body["result"]["protocol"] == protocol.VERSION


def test_options_before_the_command_and_endpoint_form(worker):
    r = probe("--json", "--timeout", "3", "--endpoint", protocol.endpoint(worker.runtime_dir), "ping")
    assert r.returncode == 0
    assert js(r)["result"]["pid"] == worker.pid


def test_default_runtime_dir_from_environment(worker):
    r = probe("ping", "--json", env={"SOVD_RUNTIME_DIR": worker.runtime_dir})
    assert r.returncode == 0
    assert js(r)["result"]["pid"] == worker.pid


def test_stats(worker):
    r = probe("--runtime-dir", worker.runtime_dir, "stats")
    assert r.returncode == 0
    assert "data_provider:" in r.stdout and "executor:" in r.stdout
    assert "worker_alive: true" in r.stdout
    body = js(probe("--runtime-dir", worker.runtime_dir, "stats", "--json"))
    assert body["result"]["executor"]["worker_alive"] is True
    assert "pool_size" in body["result"]["data_provider"]


def test_graph(worker, level_pub):
    # The topic and its node come from two discovery streams (DDS endpoints, and the
    # node's ros_discovery_info sample) that arrive in either order, so the graph can
    # list the topic before the node (ipc/PROTOCOL.md, `graph`): wait for both.
    def seen():
        body = js(probe("--runtime-dir", worker.runtime_dir, "graph", "--json"))["result"]
        node = next((n for n in body["nodes"] if n["fqn"] == "/probe_level"), None)
        return (node is not None and [TOPIC, "std_msgs/msg/Float32"] in node["publishes"]
                and any(t["name"] == TOPIC for t in body["topics"]))
    poll_until(seen, 30, interval=0.2, message="the publisher's node and topic in the graph")
    r = probe("--runtime-dir", worker.runtime_dir, "graph")
    assert r.returncode == 0
    assert "/probe_level" in r.stdout and TOPIC in r.stdout


def test_sample_and_evict(worker, level_pub):
    def data():
        r = probe("--runtime-dir", worker.runtime_dir, "sample", TOPIC, "--json", "--timeout", "3")
        body = js(r)
        return body if r.returncode == 0 and body["result"]["status"] == "data" else None
    body = poll_until(data, 30, interval=0.2, message="sample with data")
    assert body["result"]["data"] == {"data": 42.5}
    assert body["result"]["type"] == "std_msgs/msg/Float32"
    r = probe("--runtime-dir", worker.runtime_dir, "sample", TOPIC)
    assert r.returncode == 0
    assert r.stdout.startswith(f"{TOPIC} [std_msgs/msg/Float32] data")
    assert '"data": 42.5' in r.stdout
    r = probe("--runtime-dir", worker.runtime_dir, "evict", TOPIC, "--json")
    assert r.returncode == 0 and js(r)["result"] == {"topic": TOPIC, "evicted": True}
    r = probe("--runtime-dir", worker.runtime_dir, "evict", TOPIC)
    assert r.returncode == 0 and "was not pooled" in r.stdout


def test_sample_of_an_unknown_topic_is_metadata_only(worker):
    r = probe("--runtime-dir", worker.runtime_dir, "sample", "/probe_test/nobody", "--json")
    assert r.returncode == 0
    assert js(r)["result"]["status"] == "metadata_only"


def test_error_reply_exits_1(worker):
    r = probe("--runtime-dir", worker.runtime_dir, "sample", "not a topic")
    assert r.returncode == 1
    assert "invalid-topic" in r.stderr
    r = probe("--runtime-dir", worker.runtime_dir, "sample", "not a topic", "--json")
    assert r.returncode == 1
    assert js(r)["ok"] is False and js(r)["error"]["code"] == "invalid-topic"


def test_fail_degraded_exits_1_while_a_task_runs_too_long(worker):
    client = RosWorkerClient.for_runtime_dir(worker.runtime_dir)

    def sleep():
        try:
            client.call("debug_sleep", {"seconds": 2.0}, timeout=5)
        except IpcError:
            pass

    t = threading.Thread(target=sleep)
    t.start()
    try:
        def degraded():
            r = probe("--runtime-dir", worker.runtime_dir, "stats", "--fail-degraded", "--json")
            return r if r.returncode == 1 else None
        r = poll_until(degraded, 10, interval=0.05, message="degraded stats")
        assert js(r)["result"]["executor"]["degraded"] is True
    finally:
        t.join(10)
        client.close()
    poll_until(lambda: probe("--runtime-dir", worker.runtime_dir, "stats", "--fail-degraded").returncode == 0,
               10, message="not degraded any more")


@pytest.mark.parametrize("args", [
    [],                                        # no command
    ["bogus"],                                 # unknown command
    ["sample"],                                # missing topic
    ["--runtime-dir", "/x", "--endpoint", "ipc:///x", "ping"],  # exclusive
    ["--timeout", "-1", "ping"],
    ["--timeout", "soon", "ping"],
])
def test_usage_errors_exit_2(args):
    r = probe(*args)
    assert r.returncode == 2, (r.stdout, r.stderr)


def test_no_worker_exits_3(tmp_path):
    r = probe("--runtime-dir", str(tmp_path), "ping")
    assert r.returncode == 3
    assert "no ROS worker socket" in r.stderr
    r = probe("--runtime-dir", str(tmp_path), "ping", "--json")
    assert r.returncode == 3 and js(r)["error"]["code"] == "unavailable"


def test_stopped_worker_exits_3(tmp_path):
    runtime = str(tmp_path)
    proc = Proc([str(BIN / "sovd-rosworker"), "--runtime-dir", runtime], name="sovd-rosworker")
    client = RosWorkerClient.for_runtime_dir(runtime)
    try:
        poll_until(lambda: client.call("ping", timeout=1), 30, message="ROS worker ready")
        os.kill(proc.pid, signal.SIGSTOP)
        r = probe("--runtime-dir", runtime, "--timeout", "0.5", "ping", "--json")
        assert r.returncode == 3
        assert js(r)["error"]["code"] in ("deadline-exceeded", "unavailable")
        r = probe("--runtime-dir", runtime, "--timeout", "0.5", "stats")
        assert r.returncode == 3
    finally:
        os.kill(proc.pid, signal.SIGCONT)
        client.close()
        proc.stop()


def test_watch_prints_frames_from_the_events_channel_and_cleans_up(worker, level_pub):
    client = RosWorkerClient.for_runtime_dir(worker.runtime_dir)
    try:
        poll_until(lambda: client.call("sample", {"topic": TOPIC, "timeout_ms": 2000}, timeout=5)["status"]
                   == "data", 30, message="the topic pooled with data")
        r = probe("--runtime-dir", worker.runtime_dir, "watch", TOPIC, "--interval", "fast", "--count", "5",
                  "--json")
        assert r.returncode == 0, r.stderr
        frames = [json.loads(line) for line in r.stdout.splitlines()]
        assert len(frames) == 5
        assert all(f["status"] == "data" and f["data"] == {"data": 42.5} for f in frames)
        stamps = [f["ts"] for f in frames]
        assert stamps == sorted(stamps) and len(set(stamps)) == 5   # five ticks, not one frame five times
        r = probe("--runtime-dir", worker.runtime_dir, "watch", TOPIC, "--count", "2")
        assert r.returncode == 0, r.stderr
        assert len(r.stdout.splitlines()) == 2 and "[std_msgs/msg/Float32] data" in r.stdout
        # The probe's subscriptions are gone with it.
        assert client.call("sub_list", {"collection": "apps", "entity_id": "sovd-probe"})["items"] == []
    finally:
        client.close()


def test_watch_of_a_bad_topic_exits_1(worker):
    r = probe("--runtime-dir", worker.runtime_dir, "watch", "1bad")
    assert r.returncode == 1 and "invalid-topic" in r.stderr


def test_a_reader_that_stops_early_gets_no_traceback(worker, level_pub):
    """``sovd-probe graph | head -1``: the probe's later lines meet a closed pipe; it ends quietly, and a
    ``watch`` piped into ``head`` stops at the next frame and deletes its subscription."""
    client = RosWorkerClient.for_runtime_dir(worker.runtime_dir)
    try:
        poll_until(lambda: client.call("sample", {"topic": TOPIC, "timeout_ms": 2000}, timeout=5)["status"]
                   == "data", 30, message="the topic pooled with data")
        probe_bin = str(BIN / "sovd-probe")
        for command in (f"{probe_bin} --runtime-dir {worker.runtime_dir} stats | head -n 1",
                        f"{probe_bin} --runtime-dir {worker.runtime_dir} watch {TOPIC} --interval fast | head -n 2"):
            # A shell pipeline, as an operator types it; the probe's own exit status is asked for.
            r = subprocess.run(["bash", "-c", command + "; echo \"probe=${PIPESTATUS[0]}\""], capture_output=True,
                               text=True, timeout=60, cwd=REPO)
            assert "Traceback" not in r.stderr and "BrokenPipe" not in r.stderr, r.stderr
            assert r.stdout.strip().endswith("probe=0"), (command, r.stdout, r.stderr)
            assert len(r.stdout.strip().splitlines()) == int(command.rsplit(" ", 1)[1]) + 1, r.stdout
        assert client.call("sub_list", {"collection": "apps", "entity_id": "sovd-probe"})["items"] == []
    finally:
        client.close()
