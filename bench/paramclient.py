"""The reference of the configurations bench row: a bare rclpy parameter client (``python -m bench.paramclient``).

``python -m bench.paramclient /powertrain/engine/temp_sensor filter_window N`` gets the
parameter N times, then sets it N times (alternating two values), one request at a time,
each through the node's own service with ``call_async`` and ``spin_until_future_complete``;
prints one JSON line ``{"get_ms": [...], "set_ms": [...]}``.
"""

from __future__ import annotations

import json
import sys
import time

from common.harness import rosmain


def main() -> None:
    import rclpy
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import GetParameters, SetParameters

    fqn, name, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
    node, _ = rosmain.start("bench_paramclient")
    get = node.create_client(GetParameters, f"{fqn}/get_parameters")
    put = node.create_client(SetParameters, f"{fqn}/set_parameters")
    if not (get.wait_for_service(timeout_sec=20) and put.wait_for_service(timeout_sec=20)):
        print(json.dumps({"error": f"no parameter services on {fqn}"}), flush=True)
        return

    def once(client, request) -> float:
        started = time.perf_counter()
        future = client.call_async(request)
        rclpy.spin_until_future_complete(node, future, timeout_sec=5)
        if future.result() is None:
            raise RuntimeError("no answer")
        return (time.perf_counter() - started) * 1000

    for _ in range(10):  # warm-up
        once(get, GetParameters.Request(names=[name]))
    get_ms = [once(get, GetParameters.Request(names=[name])) for _ in range(n)]
    set_ms = []
    for i in range(n):
        value = ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=5 + i % 2)
        set_ms.append(once(put, SetParameters.Request(parameters=[Parameter(name=name, value=value)])))
    print(json.dumps({"get_ms": get_ms, "set_ms": set_ms}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main()
