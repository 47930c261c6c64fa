"""A real ROS 2 node with service and action servers, in its own process, for the operation tests.

Run as ``python -m tests.support.rosops '<json spec>'``::

    {"node": "calib", "namespace": "/arm",
     "services": [{"name": "calibrate", "type": "std_srvs/srv/Trigger"},
                  {"name": "echo", "type": "test_msgs/srv/BasicTypes"}],
     "actions": [{"name": "fib", "type": "test_msgs/action/Fibonacci", "step": 0.1}],
     "spin": true}

Services answer at once: a ``Trigger`` with ``success: true`` and ``message: "called <n>"``,
any other type echoes every request field that the response has (``BasicTypes``, ``Arrays``).
A service with ``"delay": s`` prints ``CALLING <n>`` when a call starts, works ``s`` seconds, and
prints ``CALLED <n>`` when it has carried the call out (a slow calibration).
The Fibonacci action server computes ``order`` numbers, one every ``step`` seconds, with
feedback after each; ``order < 0`` is rejected, ``order == 13`` aborts after its first step,
and every cancel request is accepted (the goal ends ``canceled`` at its next step).  With
``"spin": false`` the servers exist but nothing is ever answered (a server that hangs).

Prints ``READY`` once every server exists.  SIGTERM destroys the node cleanly.
"""

from __future__ import annotations

import importlib
import json
import sys
import time

from common.harness import fibonacci, rosmain

ABORT_ORDER = 13


def _load(type_name: str):
    pkg, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


def main() -> None:
    spec = json.loads(sys.argv[1])
    import rclpy
    from rclpy.action import ActionServer, CancelResponse, GoalResponse
    from rclpy.callback_groups import ReentrantCallbackGroup
    from rclpy.executors import MultiThreadedExecutor

    node, stop = rosmain.start(spec["node"], namespace=spec.get("namespace", "/"))
    group = ReentrantCallbackGroup()
    calls = {"n": 0}

    def serve(srv_type, delay: float = 0.0):
        def callback(request, response):
            calls["n"] += 1
            n = calls["n"]
            if delay:
                print(f"CALLING {n}", flush=True)
                time.sleep(delay)
                print(f"CALLED {n}", flush=True)
            fields = response.get_fields_and_field_types()
            if "success" in fields and "message" in fields and not request.get_fields_and_field_types():
                response.success = True
                response.message = f"called {n}"
                return response
            for name in fields:
                if hasattr(request, name):
                    setattr(response, name, getattr(request, name))
            return response
        return callback

    keep = []
    for item in spec.get("services", []):
        cls = _load(item["type"])
        keep.append(node.create_service(cls, item["name"], serve(cls, float(item.get("delay", 0))),
                                        callback_group=group))

    for item in spec.get("actions", []):
        cls = _load(item["type"])
        step = float(item.get("step", 0.1))

        async def pause(goal_handle, step=step):
            """``step`` seconds on this executor thread, or less once a cancel is requested."""
            deadline = time.monotonic() + step
            while time.monotonic() < deadline and not goal_handle.is_cancel_requested:
                time.sleep(0.01)

        async def execute(goal_handle, cls=cls, pause=pause):
            return await fibonacci.execute(goal_handle, cls, lambda: pause(goal_handle),
                                           aborts=lambda order: order == ABORT_ORDER)

        keep.append(ActionServer(
            node, cls, item["name"], execute_callback=execute, callback_group=group,
            goal_callback=lambda request: GoalResponse.REJECT if request.order < 0 else GoalResponse.ACCEPT,
            cancel_callback=lambda _handle: CancelResponse.ACCEPT))

    print("READY", flush=True)
    if not spec.get("spin", True):
        stop.wait()
        node.destroy_node()
        rclpy.try_shutdown()
        return
    executor = MultiThreadedExecutor(num_threads=32)
    executor.add_node(node)
    try:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
