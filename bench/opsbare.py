"""The bare rclpy reference of the operations bench row: ``N`` calls of a ``std_srvs/Trigger`` service.

    python -m bench.opsbare /arm/calibrate 200 20

One node, one client, ``call_async`` and ``spin_until_future_complete`` per call, after a warm-up
(the third argument: calls not counted).  Prints one JSON line: ``{"samples_ms": [...]}``.
"""

from __future__ import annotations

import json
import sys
import time

from common.harness import rosmain


def main() -> None:
    service, n, warmup = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    from rclpy.executors import SingleThreadedExecutor
    from std_srvs.srv import Trigger

    node, stop = rosmain.start("bench_ops_bare")
    client = node.create_client(Trigger, service)
    if not client.wait_for_service(timeout_sec=30):
        print(json.dumps({"error": f"no server of {service}"}), flush=True)
        return
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    samples = []
    for i in range(warmup + n):
        if stop.is_set():
            break
        t0 = time.perf_counter()
        future = client.call_async(Trigger.Request())
        executor.spin_until_future_complete(future, timeout_sec=10)
        if future.result() is None:
            print(json.dumps({"error": "a call was not answered in 10 s"}), flush=True)
            return
        if i >= warmup:
            samples.append((time.perf_counter() - t0) * 1000)
    print(json.dumps({"samples_ms": samples}), flush=True)
    executor.remove_node(node)
    node.destroy_node()


if __name__ == "__main__":
    main()
