"""The DDS floor of the faults bench: the fault manager's /diagnostics subscription, held, never taken.

Run as ``python -m bench.faultfloor``: subscribes to ``/diagnostics`` as the ROS worker does
(reliable, depth 100), prints ``READY`` and sleeps until SIGTERM.  Its CPU is the middleware's
cost of delivering the arrays: the least any process holding that subscription can cost.
"""

from __future__ import annotations

import sys

from common.harness import rosmain


def main() -> int:
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    node, stop = rosmain.start("bench_fault_floor", start_parameter_services=False, enable_rosout=False)
    sub = node.create_subscription(DiagnosticArray, "/diagnostics", lambda _m: None,
                                   QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    print("READY", flush=True)
    while not stop.wait(0.5):
        pass
    node.destroy_subscription(sub)
    node.destroy_node()
    return 0


if __name__ == "__main__":
    sys.exit(main())
