"""What every ROS program of the tests, the bench and the demo robot (run with ``-m``) shares.

:func:`start` records SIGTERM/SIGINT in an event (rclpy's own handlers stay
off, so a stop is a clean exit, not an exception out of the executor), inits
rclpy and makes the node (:func:`init` without the node, for a program of
several); :func:`spin` runs the callbacks until that event is set, then
destroys the nodes, so that they leave the graph at once; :func:`hold` keeps
a node's entities without spinning until then.
"""

from __future__ import annotations

import signal
import threading
import time


def init() -> threading.Event:
    """Init rclpy without its signal handlers; the event that SIGTERM or SIGINT sets."""
    import rclpy

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    rclpy.init(signal_handler_options=rclpy.SignalHandlerOptions.NO)
    return stop


def start(name: str, **node_options):
    """``(node, stop)``: a node of this process and the event a stop signal sets."""
    from rclpy.node import Node

    stop = init()
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


def spin(node, stop: threading.Event, others=(), timeout: float = 0.05) -> None:
    """Run the callbacks of the node (and of ``others`` of this process) until ``stop`` is set
    (waiting at most ``timeout`` s for one); then destroy them and shut rclpy down."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    nodes = [node, *others]
    executor = SingleThreadedExecutor()
    for each in nodes:
        executor.add_node(each)
    try:
        while not stop.is_set():
            executor.spin_once(timeout_sec=timeout)
    finally:
        for each in nodes:
            executor.remove_node(each)
            each.destroy_node()
        rclpy.try_shutdown()


def hold(node, stop: threading.Event) -> int:
    """Print ``READY``, hold the node's entities (never spun: what arrives stays in the middleware) until
    ``stop`` is set, then destroy the node and shut rclpy down; 0, the program's exit status."""
    import rclpy

    print("READY", flush=True)
    while not stop.wait(0.5):
        pass
    node.destroy_node()
    rclpy.try_shutdown()
    return 0
