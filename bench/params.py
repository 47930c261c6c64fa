"""Configurations bench rows: GET and PUT of one parameter through the gateway against a bare rclpy
parameter client (``bench/paramclient.py``), in the same run, on the demo robot's engine node.

The gateway's GET asks the node twice (``get_parameters`` and ``describe_parameters``: the value and
its descriptor) and its PUT three times (the current type, the set, and the value as the node now
reports it); the bare client asks once.  Requests are sequential on one keep-alive connection.
The gateway is one of its own, with ``--allow-configurations``.
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import time
from typing import Any

import requests

from common.harness.gateway import Gateway
from common.harness.procs import Proc, poll_until

NODE, APP, NAME = "/powertrain/engine/temp_sensor", "temp_sensor", "filter_window"
TARGET_MS = 1.0  # p50 ≤ bare + 1 ms


def _timed(fn, n: int) -> list[float]:
    out = []
    for i in range(n):
        started = time.perf_counter()
        fn(i)
        out.append((time.perf_counter() - started) * 1000)
    return out


def case(bench: Any) -> None:
    n = 30 if bench.args.quick else 300
    gw = Gateway("--allow-configurations", "--log-level", "warning",
                 log_path=os.path.join(bench.work_dir, "gateway-params.log"))
    try:
        url = f"{gw.api}/apps/{APP}/configurations/{NAME}"
        poll_until(lambda: requests.get(url, timeout=5).status_code == 200, 30, message="the demo's parameter")
        session = requests.Session()

        def get(_i: int) -> None:
            r = session.get(url, timeout=5)
            assert r.status_code == 200, r.text

        def put(i: int) -> None:
            r = session.put(url, json={"data": 5 + i % 2}, timeout=5)
            assert r.status_code == 200, r.text

        _timed(get, 10)  # warm-up: clients made, the node's record taken
        gw_get, gw_put = _timed(get, n), _timed(put, n)
        ref = Proc([sys.executable, "-m", "bench.paramclient", NODE, NAME, str(n)], name="bare param client")
        line = ref.wait_line(lambda text: text.startswith("{"), 120)
        ref.stop()
        bare = json.loads(line)
        if "error" in bare:
            raise RuntimeError(bare["error"])
    finally:
        gw.stop()
    for key, what, mine, theirs in (("param_get", "GET", gw_get, bare["get_ms"]),
                                    ("param_put", "PUT", gw_put, bare["set_ms"])):
        p50, ref50 = statistics.median(mine), statistics.median(theirs)
        values = {"n": n, "p50_ms": round(p50, 3), "bare_p50_ms": round(ref50, 3),
                  "p99_ms": round(sorted(mine)[int(0.99 * (n - 1))], 3)}
        bench.add(key, f"configurations: {what} one parameter vs a bare rclpy parameter client",
                  f"{n} sequential requests, one keep-alive connection; bare: call_async + "
                  "spin_until_future_complete, same node, same run", values,
                  f"p50 {p50:.2f} ms vs bare {ref50:.2f} ms (p99 {values['p99_ms']:.2f} ms)",
                  f"p50 ≤ bare + {TARGET_MS:g} ms", p50 <= ref50 + TARGET_MS)
