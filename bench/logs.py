"""``make bench``'s logs row (issue 22): the ROS worker's CPU with /rosout at 1 kHz, beside its DDS floor.

A node (``bench/roslogger.py``) publishes 1,000 /rosout lines a second;
the ROS worker takes them into its ring buffers (``rosworker/logs/book.py``) while
``bench/rosoutfloor.py`` holds the same subscription and never reads it.  Both
are measured over the same window, and over one as long before the lines
start (each process's baseline: the worker also polls the graph).
"""

from __future__ import annotations

import threading
import time

import psutil

from common.harness.roslogger import LoggerNode

from .procs import measure_cpu, ros_helper

RATE_HZ = 1000
TARGET_RATIO = 1.5


def case_rosout(bench) -> None:
    seconds = bench.p["idle_s"]
    floor = ros_helper("rosoutfloor", name="rosoutfloor")
    bench.procs.append(floor)
    logger = LoggerNode("bench_rosout")
    bench.procs.append(logger)
    procs = {"rosworker": bench.gw.rosworker(), "rosoutfloor": psutil.Process(floor.pid)}
    time.sleep(1.0)  # matching settles
    base = measure_cpu(procs, seconds)
    written: list[int] = []
    storm = threading.Thread(target=lambda: written.append(logger.storm(RATE_HZ, seconds + 2.0)), daemon=True)
    received = bench.gw.get("/health").json()["x-medkit-logs"]["logs_received"]
    storm.start()
    time.sleep(1.0)
    cpu = measure_cpu({**procs, "logger": psutil.Process(logger.pid)}, seconds)
    storm.join(timeout=seconds + 30)
    taken = bench.gw.get("/health").json()["x-medkit-logs"]["logs_received"] - received
    ratio = cpu["rosworker"] / cpu["rosoutfloor"] if cpu["rosoutfloor"] > 0 else float("inf")
    added = cpu["rosworker"] - base["rosworker"]
    added_floor = cpu["rosoutfloor"] - base["rosoutfloor"]
    values = {**{k: round(v * 100, 2) for k, v in cpu.items()},
              **{f"{k}_baseline": round(v * 100, 2) for k, v in base.items()},
              "rate_hz": RATE_HZ, "seconds": seconds, "lines_written": written[0] if written else None,
              "lines_taken": taken, "ratio": round(ratio, 3),
              "added_ratio": round(added / added_floor, 3) if added_floor > 0 else None}
    bench.add("rosout", f"logs: ROS worker CPU with /rosout at {RATE_HZ} Hz",
              f"psutil cpu_times over {seconds:g} s, same window as bench/rosoutfloor.py (one /rosout "
              "subscription with rosout's QoS, never read); baselines over as long before the lines start",
              values, f"worker {values['rosworker']:.1f}% of a core (baseline {values['rosworker_baseline']:.1f}%) "
              f"vs DDS floor {values['rosoutfloor']:.1f}% (baseline {values['rosoutfloor_baseline']:.1f}%) = "
              f"{ratio:.2f} × floor; {taken} lines taken",
              f"≤ {TARGET_RATIO} × floor", ratio <= TARGET_RATIO)
    bench.stop_proc(logger)
    bench.stop_proc(floor)
