"""What every ROS program of the tests and the bench (``bench/*.py``, ``tests/support/rospub.py``, run with ``-m``) shares.

:func:`start` records SIGTERM/SIGINT in an event (rclpy's own handlers stay
off, so a stop is a clean exit, not an exception out of the executor), inits
rclpy and makes the node; :func:`spin` runs its callbacks until that event is
set, then destroys the node, so that it leaves the graph at once.
"""

from __future__ import annotations

import signal
import threading
import time


def start(name: str, **node_options):
    """``(node, stop)``: a node of this process and the event a stop signal sets."""
    import rclpy
    from rclpy.node import Node

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    rclpy.init(signal_handler_options=rclpy.SignalHandlerOptions.NO)
    return Node(name, **node_options), stop


def wait_for_publishers(node, topic: str, timeout: float, stop: threading.Event) -> list:
    """The topic's publisher infos once there is one; ``[]`` after ``timeout`` or a stop signal."""
    deadline = time.monotonic() + timeout
    while not stop.is_set():
        infos = node.get_publishers_info_by_topic(topic)
        if infos or time.monotonic() >= deadline:
            return infos
        time.sleep(0.05)
    return []


def spin(node, stop: threading.Event, others=()) -> None:
    """Run the callbacks of the node (and of ``others`` of this process) until ``stop`` is set; then
    destroy them and shut rclpy down."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    nodes = [node, *others]
    executor = SingleThreadedExecutor()
    for each in nodes:
        executor.add_node(each)
    try:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)
    finally:
        for each in nodes:
            executor.remove_node(each)
            each.destroy_node()
        rclpy.try_shutdown()
