"""The DDS floor of the logs case: one /rosout subscription with rosout's QoS, held but never spun.

Run as ``python -m bench.rosoutfloor`` (by ``make bench``).  Subscribes to
``/rosout`` exactly as the ROS worker does (``rosworker/logs/book.py``: reliable,
transient-local, keep-last 1000), prints ``READY`` and sleeps until SIGTERM.
Its CPU is the middleware's cost of delivering /rosout into that reader's
history: the least any process holding the subscription can cost.
"""

from __future__ import annotations

import sys

from common.harness import rosmain


def main() -> int:
    from rcl_interfaces.msg import Log
    from rclpy.duration import Duration
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    from rosworker.logs.book import ROSOUT_DEPTH, ROSOUT_LIFESPAN_S

    node, stop = rosmain.start("bench_rosout_floor", start_parameter_services=False, enable_rosout=False)
    profile = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=ROSOUT_DEPTH, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL, lifespan=Duration(seconds=ROSOUT_LIFESPAN_S))
    node.create_subscription(Log, "/rosout", lambda _m: None, profile)
    return rosmain.hold(node, stop)


if __name__ == "__main__":
    sys.exit(main())
