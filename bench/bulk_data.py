"""Bulk data bench (issue 32): what recording costs, and how fast a recording downloads.

``make bench`` (``bench/run.py``) runs :func:`case` (three rows); ``python -m bench.bulk_data
[--quick]`` runs them alone and prints one JSON document.  Each figure is a ratio within one run.

| row | how | target |
|---|---|---|
| ``rosbag_cpu`` | 10 topics at 100 Hz (``bench/benchpub.py``); two gateways side by side, one recording them (``fault_rosbag_topics``), the other with them merely pooled; both ROS workers' CPU in the same window | recording ≤ 1.3 × pooled |
| ``rosbag_write_sample`` | a gateway recording the 10 topics and a 640×480 image at 10 Hz; warm samples of one topic (1 connection) while recordings are written (a fault confirmed, its window closed, until the file is listed) against samples while none is | p50 during ≤ 1.1 × without |
| ``rosbag_download`` | a 200 MB recording (random payloads: incompressible) written with the gateway's own writer into its directory before it starts; ``curl`` downloads it from the gateway and from nginx (``sendfile on``) serving the same file, alternating | gateway ≥ 0.8 × nginx |
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import requests

from bench.procs import measure_cpu, robot
from common.harness.diagpub import DiagPub
from common.harness.gateway import Gateway
from common.harness.procs import Proc, free_port, poll_until, private_ros_domain

TOPICS = [f"/bench/rec/t{i}" for i in range(10)]
IMAGE = "/bench/rec/image"
RATE_HZ = 100
CPU_RATIO, P50_RATIO, DOWNLOAD_RATIO = 1.3, 1.1, 0.8
FULL = {"cpu_s": 10.0, "write_rounds": 8, "quiet_n": 400, "download_mb": 200, "download_rounds": 5}
QUICK = {"cpu_s": 1.0, "write_rounds": 1, "quiet_n": 20, "download_mb": 8, "download_rounds": 1}
PUBLISHER_NODE = "bench_rec"


class _Counters(dict):
    """What the gateway's writer counts into (``Stats`` attributes), for a writer run outside a gateway."""

    def __getattr__(self, name: str) -> int:
        return self.get(name, 0)

    def __setattr__(self, name: str, value) -> None:
        self[name] = value


def _gateway(log_dir: str, name: str, *args: str) -> Gateway:
    return Gateway("--log-level", "warning", *args, log_path=os.path.join(log_dir, f"gateway-{name}.log"))


def _health(gw: Gateway) -> dict[str, Any]:
    return gw.get("/health").json()["x-medkit-bulk-data"]


# ---- recording 10 topics vs pooling them ---------------------------------------------------------------
def measure_cpu_ratio(p: dict, log_dir: str) -> dict[str, Any]:
    with contextlib.ExitStack() as running:
        running.enter_context(robot(PUBLISHER_NODE, [{"prefix": "/bench/rec/t", "count": len(TOPICS), "rate": RATE_HZ,
                                                      "kind": "small"}]))
        recording = running.enter_context(_gateway(log_dir, "recording", "--fault-rosbag-enabled",
                                                   "--fault-rosbag-topics", ",".join(TOPICS)))
        pooled = running.enter_context(_gateway(log_dir, "pooled"))
        client = pooled.rosworker_client()
        try:
            poll_until(lambda: all(client.call("subscribe", {"topic": t}, 5)["status"] == "pooled" for t in TOPICS),
                       30, interval=0.2, message="the topics pooled")
        finally:
            client.close()
        poll_until(lambda: _health(recording)["rosbag_topics_recorded"] == len(TOPICS), 30, interval=0.2,
                   message="the topics recorded")
        time.sleep(2.0)  # matching settles, the ring fills to its window
        taken = _health(recording)["rosbag_messages"]
        cpu = measure_cpu({"recording": recording.rosworker(), "pooled": pooled.rosworker()}, p["cpu_s"])
        taken = _health(recording)["rosbag_messages"] - taken
    return {"cpu": cpu, "messages_taken": taken}


# ---- warm samples during a recording's write ----------------------------------------------------------
def measure_write_latency(p: dict, log_dir: str) -> dict[str, Any]:
    quiet: list[float] = []
    during: list[float] = []
    with contextlib.ExitStack() as running:
        running.enter_context(robot(PUBLISHER_NODE, [
            {"prefix": "/bench/rec/t", "count": len(TOPICS), "rate": RATE_HZ, "kind": "small"},
            {"topic": IMAGE, "rate": 10, "kind": "image"}]))
        gw = running.enter_context(_gateway(log_dir, "write", "--fault-rosbag-enabled", "--fault-rosbag-topics",
                                            ",".join([*TOPICS, IMAGE]), "--fault-rosbag-duration-after-s", "0.5"))
        diag = DiagPub("bench_rec_diag", rate=10)
        running.callback(diag.stop)
        diag.matched()
        poll_until(lambda: gw.get(f"/apps/{PUBLISHER_NODE}").status_code == 200, 30, message="the publisher")
        url = f"{gw.api}/apps/{PUBLISHER_NODE}/data{TOPICS[0]}"
        session = requests.Session()

        def sample(into: list[float]) -> None:
            started = time.perf_counter()
            r = session.get(url, timeout=10)
            into.append((time.perf_counter() - started) * 1000)
            assert r.status_code == 200

        for _ in range(20):
            sample([])  # warm
        time.sleep(5.5)  # the ring holds its whole window
        for i in range(p["write_rounds"]):
            health = _health(gw)
            for _ in range(p["quiet_n"] // max(1, p["write_rounds"])):
                sample(quiet)
            diag.set([{"name": f"bench recording {i}", "level": 2, "message": "bench"}])
            poll_until(lambda h=health: _health(gw)["rosbag_recordings_written"] > h["rosbag_recordings_written"]
                       or _health(gw)["rosbag_writes_pending"] > 0, 30, interval=0.01, message="a write")
            # sample until the file is listed: every sample here overlaps the writer's work
            while _health(gw)["rosbag_recordings_written"] <= health["rosbag_recordings_written"]:
                sample(during)
            diag.set([{"name": f"bench recording {i}", "level": 0, "message": "ok"}])
            time.sleep(5.5)  # the ring fills again: the next write is as large
        written = _health(gw)["rosbag_recordings_written"]
    return {"quiet_ms": quiet, "during_ms": during, "written": written}


# ---- downloading a 200 MB recording vs nginx --------------------------------------------------------
def write_recording(directory: str, size_mb: int, source: str) -> dict[str, Any]:
    """A recording of ``size_mb`` MB of random payloads, written by the gateway's own writer (its index
    takes it at start); owned by a fault of ``source``."""
    from rclpy.serialization import serialize_message
    from std_msgs.msg import UInt8MultiArray

    from rosworker.bulk_data.recorder import Recording
    from rosworker.bulk_data.writer import RecordingStore

    payload = 1 << 20
    template = serialize_message(UInt8MultiArray(data=bytes(payload)))
    prefix = template[:-payload]
    now = time.time_ns()
    channel = ("/bench/blob", "std_msgs/msg/UInt8MultiArray")
    items = [(now - (size_mb - i) * 10_000_000, now - (size_mb - i) * 10_000_000, channel,
              prefix + os.urandom(payload)) for i in range(size_mb)]
    recording = Recording(f"fault_BENCH_DOWNLOAD_{now // 1_000_000}", "BENCH_DOWNLOAD", [source], now, items,
                          1 << 40)
    store = RecordingStore(directory, _Counters(), max_total_bytes=1 << 40, max_per_fault=0)
    meta = store.write(recording)
    assert meta is not None, "the recording could not be written"
    return meta


def _curl(url: str) -> float:
    """Bytes per second of one download to /dev/null."""
    out = subprocess.run(["curl", "-sS", "-o", "/dev/null", "-w", "%{size_download} %{time_total}", url],
                         capture_output=True, text=True, timeout=600, check=True).stdout.split()
    return float(out[0]) / float(out[1])


def _nginx(root: str, work: Path) -> tuple[Proc, str]:
    """nginx serving ``root`` at ``/rosbags/`` with sendfile (its usual static-file setting); (process, URL)."""
    binary = shutil.which("nginx") or "/usr/sbin/nginx"
    port = free_port()
    for d in ("logs", "client_body", "proxy", "fastcgi", "uwsgi", "scgi"):
        (work / d).mkdir(parents=True, exist_ok=True)
    user = "user root;\n" if os.geteuid() == 0 else ""
    (work / "nginx.conf").write_text(f"""{user}worker_processes 1;
events {{ worker_connections 64; }}
http {{
    default_type application/octet-stream;
    access_log off;
    client_body_temp_path {work}/client_body; proxy_temp_path {work}/proxy; fastcgi_temp_path {work}/fastcgi;
    uwsgi_temp_path {work}/uwsgi; scgi_temp_path {work}/scgi;
    server {{ listen 127.0.0.1:{port}; sendfile on; tcp_nopush on;
        location /rosbags/ {{ alias {root}/; }} }}
}}
""")
    proc = Proc([binary, "-p", str(work), "-c", str(work / "nginx.conf"), "-e", str(work / "logs" / "error.log"),
                 "-g", f"daemon off; pid {work}/nginx.pid;"], name="nginx")
    url = f"http://127.0.0.1:{port}/rosbags/"
    poll_until(lambda: requests.get(url, timeout=2).status_code in (403, 404), 20, message="nginx listening")
    return proc, url


def measure_download(p: dict, log_dir: str) -> dict[str, Any]:
    rates: dict[str, list[float]] = {"gateway": [], "nginx": []}
    with contextlib.ExitStack() as running:
        state = tempfile.mkdtemp(prefix="bench-bulk-")
        running.callback(shutil.rmtree, state, ignore_errors=True)
        running.enter_context(robot(PUBLISHER_NODE, [{"prefix": "/bench/rec/t", "count": 1, "rate": 1,
                                                      "kind": "small"}]))
        meta = write_recording(os.path.join(state, "rosbags"), p["download_mb"], f"/{PUBLISHER_NODE}")
        gw = running.enter_context(_gateway(log_dir, "download", "--state-dir", state))
        poll_until(lambda: gw.get(f"/apps/{PUBLISHER_NODE}").status_code == 200, 30, message="the publisher")
        nginx, base = _nginx(os.path.dirname(meta["path"]), Path(tempfile.mkdtemp(prefix="bench-nginx-")))
        running.enter_context(nginx)
        urls = {"gateway": f"{gw.api}/apps/{PUBLISHER_NODE}/bulk-data/rosbags/{meta['id']}",
                "nginx": f"{base}{meta['id']}.mcap"}
        for name, url in urls.items():  # both serve the same bytes
            assert int(requests.head(url, timeout=10).headers["Content-Length"]) == meta["size"], name
        for _ in range(p["download_rounds"]):
            for name, url in urls.items():
                rates[name].append(_curl(url))
    return {"rates": rates, "size": meta["size"]}


# ---- the rows ---------------------------------------------------------------------------------------------
def rows(p: dict, log_dir: str) -> list[tuple]:
    """``(key, case, how, values, measured, target, passed)`` of the three rows."""
    out = []
    m = measure_cpu_ratio(p, log_dir)
    cpu = m["cpu"]
    ratio = cpu["recording"] / cpu["pooled"] if cpu["pooled"] > 0 else None
    values = {"recording": round(cpu["recording"] * 100, 2), "pooled": round(cpu["pooled"] * 100, 2),
              "ratio": round(ratio, 3) if ratio is not None else None, "topics": len(TOPICS), "rate_hz": RATE_HZ,
              "seconds": p["cpu_s"], "messages_taken": m["messages_taken"]}
    out.append(("rosbag_cpu", f"bulk data: ROS worker CPU recording {len(TOPICS)} topics at {RATE_HZ} Hz",
                "two gateways side by side: one records the topics (fault_rosbag_topics), the other holds them "
                "pooled; psutil cpu_times of both ROS workers over the same window", values,
                f"recording {values['recording']:.1f}% vs pooled {values['pooled']:.1f}% of a core = "
                + (f"{ratio:.2f} ×" if ratio is not None else "no ratio (under one tick)"),
                f"≤ {CPU_RATIO} × pooled", ratio is not None and ratio <= CPU_RATIO))
    m = measure_write_latency(p, log_dir)
    quiet, during = statistics.median(m["quiet_ms"]), statistics.median(m["during_ms"] or [float("inf")])
    ratio = during / quiet
    values = {"quiet_p50_ms": round(quiet, 3), "during_p50_ms": round(during, 3), "ratio": round(ratio, 3),
              "quiet_n": len(m["quiet_ms"]), "during_n": len(m["during_ms"]), "recordings_written": m["written"]}
    out.append(("rosbag_write_sample", "bulk data: warm sample p50 while recordings are written",
                f"1 connection, GET of one of {len(TOPICS)} recorded topics (a 640×480 image recorded too); samples "
                "from a fault's window closing until its file is listed, against samples while nothing is written",
                values, f"p50 {during:.2f} ms during writes vs {quiet:.2f} ms without = {ratio:.2f} × "
                f"({len(m['during_ms'])} samples over {m['written']} writes)",
                f"≤ {P50_RATIO} × without", ratio <= P50_RATIO and bool(m["during_ms"])))
    m = measure_download(p, log_dir)
    gateway, nginx = statistics.median(m["rates"]["gateway"]), statistics.median(m["rates"]["nginx"])
    ratio = gateway / nginx
    values = {"gateway_mb_s": round(gateway / 2**20, 1), "nginx_mb_s": round(nginx / 2**20, 1),
              "ratio": round(ratio, 3), "size_bytes": m["size"], "rounds": len(m["rates"]["gateway"])}
    out.append(("rosbag_download", f"bulk data: download of a {m['size'] // 2**20} MB recording",
                "curl to /dev/null, alternating: GET .../bulk-data/rosbags/{id} from the gateway, and the same file "
                "from nginx (sendfile on); medians", values,
                f"gateway {values['gateway_mb_s']:.0f} MB/s vs nginx {values['nginx_mb_s']:.0f} MB/s = {ratio:.2f} ×",
                f"≥ {DOWNLOAD_RATIO} × nginx", ratio >= DOWNLOAD_RATIO))
    return out


def case(bench: Any) -> None:
    """``make bench``'s bulk-data rows (issue 32)."""
    for row in rows(QUICK if bench.args.quick else FULL, bench.work_dir):
        bench.add(*row)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bench.bulk_data")
    parser.add_argument("--quick", action="store_true", help="briefly, small sizes (a smoke run)")
    args = parser.parse_args(argv)
    private_ros_domain()
    log_dir = tempfile.mkdtemp(prefix="bench-bulk-logs-")
    out = rows(QUICK if args.quick else FULL, log_dir)
    print(json.dumps({key: {"measured": measured, "target": target, "passed": passed, "values": values}
                      for key, _case, _how, values, measured, target, passed in out}, indent=2))
    return 0 if args.quick or all(r[-1] for r in out) else 2


if __name__ == "__main__":
    sys.exit(main())
