"""The old design, for comparison: subscribe per request.

Run as ``python -m bench.oldsampler TOPIC COUNT [TIMEOUT_S]`` (by ``make bench``).  Each of
COUNT samples creates a subscription (QoS matched to the publishers with the
pool's own rules), spins until its first message arrives, destroys it, and
records the time from "create" to "message in hand".  Requests start at a
random phase against the publisher's ticks.  This is what the C++
gateway's first design did for every HTTP read; here it runs in its own
rclpy process with no HTTP in front, so its figures are a lower bound of
that design's latency.

Prints ``READY`` once the topic's publisher is discovered, then one JSON line
``{"samples_ms": [...], "timeouts": n}``.
"""

from __future__ import annotations

import json
import random
import sys
import time

from common.harness import rosmain


def main() -> int:
    topic, count = sys.argv[1], int(sys.argv[2])
    timeout = float(sys.argv[3]) if len(sys.argv) > 3 else 2.0
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from rosworker.ros import msgtypes, qos

    node, stop = rosmain.start("bench_old_sampler", start_parameter_services=False, enable_rosout=False)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    infos = rosmain.wait_for_publishers(node, topic, 30, stop)
    if not infos:
        print(json.dumps({"error": f"no publisher on {topic}"}), flush=True)
        return 1
    cls = msgtypes.load_type(infos[0].topic_type)
    profile = qos.match_qos(infos)
    print("READY", flush=True)

    samples, timeouts = [], 0
    rng = random.Random(11)
    for _ in range(count):
        if stop.is_set():  # SIGTERM: report what was measured so far
            break
        # A random phase against the publisher's ticks, as requests from clients would have
        # (a loop that starts right after a message would always wait almost a whole period).
        time.sleep(rng.uniform(0, 0.1))
        got: list = []
        start = time.perf_counter()
        sub = node.create_subscription(cls, topic, got.append, profile)
        end = time.monotonic() + timeout
        while not got and time.monotonic() < end:
            executor.spin_once(timeout_sec=max(0.0, end - time.monotonic()))
        elapsed = time.perf_counter() - start
        node.destroy_subscription(sub)
        if got:
            samples.append(round(elapsed * 1000, 3))
        else:
            timeouts += 1
    print(json.dumps({"samples_ms": samples, "timeouts": timeouts}), flush=True)
    executor.remove_node(node)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
