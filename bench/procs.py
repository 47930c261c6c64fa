"""The bench's own processes and CPU figures; the rest comes from the harness it shares with the tests.

The private ROS domain (:func:`common.harness.procs.private_ros_domain`), the
gateway (:class:`common.harness.gateway.Gateway`, with its output to a log file)
and process handling (:class:`common.harness.procs.Proc`) are common/harness/'s.  Here:

- :func:`ros_helper` starts ``python -m bench.<module>`` and waits for ``READY``;
  :func:`robot` is that for the publishers of ``bench/benchpub.py``;
- :func:`cpu_seconds` and :func:`measure_cpu`: what processes used, from psutil.
"""

from __future__ import annotations

import json
import sys
import time

import psutil

from common.harness.procs import Proc


def ros_helper(module: str, *args: str, name: str | None = None, timeout: float = 60.0) -> Proc:
    """``python -m bench.<module> ARGS`` in its own process; returns once it printed READY.

    The bench's ROS nodes live in ``bench/`` (exempt from "only ``rosworker/`` of the
    gateway creates ROS entities"; tests/test_layout.py).
    """
    proc = Proc([sys.executable, "-m", f"bench.{module}", *args], name=name or module)
    proc.wait_line(lambda line: line == "READY", timeout)
    return proc


def robot(node: str, groups: list[dict], timeout: float = 60.0) -> Proc:
    return ros_helper("benchpub", json.dumps({"node": node, "groups": groups}), name=node, timeout=timeout)


def cpu_seconds(proc: psutil.Process) -> float:
    t = proc.cpu_times()
    return t.user + t.system


def measure_cpu(procs: dict[str, psutil.Process], seconds: float) -> dict[str, float]:
    """Share of one core each process used over the same ``seconds`` window."""
    before = {k: cpu_seconds(p) for k, p in procs.items()}
    start = time.monotonic()
    time.sleep(seconds)
    wall = time.monotonic() - start
    return {k: (cpu_seconds(p) - before[k]) / wall for k, p in procs.items()}
