"""Faults bench: the ROS worker's CPU for /diagnostics at 10 Hz × 50 statuses against the DDS floor,
and the latency from a failing status's publish to its confirmed fault in ``GET /faults``.

Run as ``python -m bench.faults [--seconds S] [--trials N]`` (short: a few seconds each).  Prints
one JSON document.  The floor is a process that holds the same subscription (reliable, depth 100)
and never takes from it (``bench.faultfloor``), measured in the same window as the worker; the
worker's own idle cost (no /diagnostics) is measured first, in a window of the same length.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time

import psutil
import requests

from bench.diagpub import DiagPub
from bench.procs import measure_cpu
from tests.support.gateway import Gateway
from tests.support.procs import Proc, poll_until, private_ros_domain


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bench.faults")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--trials", type=int, default=20)
    args = parser.parse_args(argv)
    private_ros_domain()
    gw = Gateway("--fault-confirm-count", "1", "--fault-stale-s", "0", log_path="/tmp/bench-faults-gateway.log")
    pubs: list[DiagPub] = []
    floor = None
    try:
        worker = psutil.Process(gw.rosworker_pid())
        idle = measure_cpu({"worker": worker}, args.seconds)["worker"]
        load = DiagPub("bench_diag", rate=10)
        pubs.append(load)
        load.set([{"name": f"bench status {i}", "level": 0, "message": "ok", "values": {"v": str(i)}}
                  for i in range(50)])
        floor = Proc([sys.executable, "-m", "bench.faultfloor"], name="fault floor")
        floor.wait_line(lambda line: line == "READY", 60)
        time.sleep(1.0)
        cpu = measure_cpu({"worker": worker, "floor": psutil.Process(floor.pid)}, args.seconds)
        arrays_before = gw.get("/health").json()["x-medkit-faults"]["diagnostics_arrays"]
        time.sleep(1.0)
        arrays_rate = gw.get("/health").json()["x-medkit-faults"]["diagnostics_arrays"] - arrays_before
        # confirm latency: one failing status per trial, its code polled every 5 ms
        probe = DiagPub("bench_latency", rate=10)
        pubs.append(probe)
        latencies = []
        for trial in range(args.trials):
            code = f"BENCH_LATENCY_{trial}"
            started = time.monotonic()
            probe.set([{"name": f"bench latency {trial}", "level": 2, "message": "bad"}])

            def confirmed(code=code) -> bool:
                items = requests.get(gw.api + "/faults?status=confirmed", timeout=5).json()["items"]
                return any(f["fault_code"] == code for f in items)

            poll_until(confirmed, 10, interval=0.005, message=code)
            latencies.append((time.monotonic() - started) * 1000)
        result = {
            "diagnostics": "10 Hz x 50 statuses", "seconds": args.seconds,
            "worker_idle_cpu": round(idle, 4), "worker_cpu": round(cpu["worker"], 4),
            "worker_cpu_added": round(cpu["worker"] - idle, 4), "dds_floor_cpu": round(cpu["floor"], 4),
            "arrays_per_s_seen": arrays_rate,
            "confirm_latency_ms": {"p50": round(statistics.median(latencies), 1),
                                   "max": round(max(latencies), 1), "trials": len(latencies),
                                   "note": "from the control file write (the publisher polls it every 20 ms)"},
        }
        print(json.dumps(result, indent=2))
    finally:
        for pub in pubs:
            pub.stop()
        if floor is not None:
            floor.stop()
        gw.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
