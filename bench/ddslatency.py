"""The DDS-alone reference of the stream-image case: publish stamp to an rclpy callback.

Run as ``python -m bench.ddslatency '{"topic": ..., "seconds": ..., "skip": ...}'`` (by
``bench/streams.py``).  Subscribes to an image topic with a plain rclpy
subscription (the pool's QoS rules), spins, and for each message after the
first ``skip`` seconds records the time from its ``header.stamp`` (the
publisher's clock, on this machine) to the callback; prints one JSON line
``{"n", "p50_ms", "p99_ms"}`` after ``seconds``.  This is what the middleware
alone takes to deliver the same messages in the same run: the floor under the
gateway's publish → client latency.
"""

from __future__ import annotations

import json
import statistics
import sys
import threading
import time

from common.harness import rosmain


def main() -> int:
    spec = json.loads(sys.argv[1])
    from rosworker.ros import msgtypes, qos

    node, stop = rosmain.start("bench_dds_latency", start_parameter_services=False, enable_rosout=False)
    infos = rosmain.wait_for_publishers(node, spec["topic"], 60, stop)
    if not infos:
        print(json.dumps({"n": 0, "p50_ms": float("nan"), "p99_ms": float("nan")}), flush=True)
        return 1
    lags: list[float] = []
    started = time.time()

    def received(msg) -> None:
        now = time.time()
        if now - started >= spec.get("skip", 0.0):
            lags.append((now - (msg.header.stamp.sec + msg.header.stamp.nanosec / 1e9)) * 1000)

    node.create_subscription(msgtypes.load_type(infos[0].topic_type), spec["topic"], received,
                             qos.match_qos(infos))
    timer = threading.Timer(spec["seconds"], stop.set)
    timer.start()
    rosmain.spin(node, stop)
    lags.sort()
    print(json.dumps({"n": len(lags), "p50_ms": statistics.median(lags) if lags else float("nan"),
                      "p99_ms": lags[min(len(lags) - 1, int(0.99 * (len(lags) - 1)))] if lags else float("nan")}),
          flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
