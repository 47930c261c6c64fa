"""The operations bench row: a ``std_srvs/Trigger`` call through the gateway against the same call
from a bare rclpy client (``bench/opsbare.py``), in the same run, on the demo robot's
``/arm/calibrate`` (``demo/calibration.py``).

Gateway: ``POST /api/v1/apps/calibration/operations/calibrate/executions`` on one keep-alive
connection (Python ``requests``; its own cost is in the figure, as ``GET /version-info`` on the same
connection shows: reported beside).  Target: p50 ≤ bare p50 + 1 ms.
"""

from __future__ import annotations

import json
import statistics
import sys
import time

import requests

from common.harness.procs import Proc, poll_until

PATH = "/apps/calibration/operations/calibrate/executions"
SERVICE = "/arm/calibrate"
MARGIN_MS = 1.0


def _p50(samples: list[float]) -> float:
    return statistics.median(samples) if samples else float("inf")


def case_trigger(bench) -> None:
    n, warmup = (10, 3) if bench.args.quick else (400, 20)
    session = requests.Session()
    url = bench.gw.api + PATH
    poll_until(lambda: session.post(url, json={}, timeout=10).status_code == 200, 60, interval=0.2,
               message="the demo's calibrate service through the gateway")
    gateway, floor = [], []
    for i in range(n + warmup):
        t0 = time.perf_counter()
        r = session.post(url, json={}, timeout=10)
        took = (time.perf_counter() - t0) * 1000
        assert r.status_code == 200, r.text
        t0 = time.perf_counter()
        session.get(bench.gw.api + "/version-info", timeout=10)
        if i >= warmup:
            gateway.append(took)
            floor.append((time.perf_counter() - t0) * 1000)
    session.close()
    proc = Proc([sys.executable, "-m", "bench.opsbare", SERVICE, str(n), str(warmup)], name="opsbare")
    line = proc.wait_line(lambda x: x.startswith("{"), 60 + n * 0.1)
    proc.stop(timeout=5)
    bare = json.loads(line).get("samples_ms", [])
    g50, b50, f50 = _p50(gateway), _p50(bare), _p50(floor)
    bench.add("trigger", "service call (std_srvs/Trigger)",
              f"POST …/operations/calibrate/executions, 1 connection, {n} calls; bare rclpy client "
              "(bench/opsbare.py) in the same run",
              {"gateway_p50_ms": round(g50, 3), "bare_p50_ms": round(b50, 3),
               "gateway_p99_ms": round(sorted(gateway)[int(len(gateway) * 0.99) - 1], 3) if gateway else None,
               "floor_p50_ms": round(f50, 3), "n": n},
              f"gateway p50 {g50:.2f} ms, bare {b50:.2f} ms (+{g50 - b50:.2f} ms); "
              f"GET /version-info on the same connection {f50:.2f} ms",
              f"p50 ≤ bare + {MARGIN_MS:g} ms", g50 <= b50 + MARGIN_MS)
