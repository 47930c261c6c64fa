"""A long-lived rclpy node that creates and destroys publishers on command, and counts endpoints.

Run as ``python -m tests.reliability.churn_node NODE_NAME``.  Starting a
process per publisher is slow; this one process makes publisher churn fast.
Commands arrive as JSON lines on stdin; each gets one JSON reply line on
stdout carrying the command's ``seq``::

    {"seq": 1, "op": "pub", "id": "a", "topic": "/x", "type": "std_msgs/msg/String",
     "rate": 20, "value": {"data": "c1"}}                 -> {"seq": 1, "ok": true}
    {"seq": 2, "op": "unpub", "id": "a"}                   -> {"seq": 2, "ok": true}
    {"seq": 3, "op": "count", "topic": "/x"}               -> {"seq": 3, "ok": true,
                                                               "publishers": 0, "subscribers": 1}
    {"seq": 4, "op": "quit"}

``count`` is this node's independent view of the ROS graph: it is how a test
sees whether the gateway still holds a subscription on a topic.  A publisher
publishes its value once at once and then at ``rate`` Hz.  Every rclpy call
runs on the main thread; a reader thread only queues the lines.  Prints
``READY`` once the node exists.
"""

from __future__ import annotations

import importlib
import json
import queue
import signal
import sys
import threading


def _load(type_name: str):
    pkg, _, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def main() -> None:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    commands: queue.Queue = queue.Queue()

    def read_stdin() -> None:
        for line in sys.stdin:
            if line.strip():
                commands.put(line)
        commands.put('{"op": "quit"}')

    rclpy.init()
    node = Node(sys.argv[1] if len(sys.argv) > 1 else "churn")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    publishers: dict[str, tuple] = {}

    def drop(pid: str) -> None:
        pub, timer = publishers.pop(pid)
        node.destroy_timer(timer)
        node.destroy_publisher(pub)

    def handle(cmd: dict) -> dict:
        op = cmd.get("op")
        if op == "pub":
            if cmd["id"] in publishers:
                drop(cmd["id"])
            cls = _load(cmd["type"])
            pub = node.create_publisher(cls, cmd["topic"], QoSProfile(depth=1))
            msg = cls()
            for key, value in cmd.get("value", {}).items():
                setattr(msg, key, value)
            pub.publish(msg)
            timer = node.create_timer(1.0 / float(cmd.get("rate", 10)), lambda p=pub, m=msg: p.publish(m))
            publishers[cmd["id"]] = (pub, timer)
            return {"ok": True}
        if op == "unpub":
            if cmd["id"] in publishers:
                drop(cmd["id"])
            return {"ok": True}
        if op == "count":
            return {"ok": True, "publishers": node.count_publishers(cmd["topic"]),
                    "subscribers": node.count_subscribers(cmd["topic"])}
        if op == "quit":
            stop.set()
            return {"ok": True}
        return {"ok": False, "error": f"unknown op {op!r}"}

    threading.Thread(target=read_stdin, daemon=True).start()
    print("READY", flush=True)
    try:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.01)
            while True:
                try:
                    line = commands.get_nowait()
                except queue.Empty:
                    break
                try:
                    cmd = json.loads(line)
                    reply = handle(cmd)
                except Exception as exc:  # a bad command must not end the helper
                    cmd, reply = {}, {"ok": False, "error": repr(exc)}
                print(json.dumps({"seq": cmd.get("seq"), **reply}), flush=True)
    finally:
        for pid in list(publishers):
            drop(pid)
        executor.remove_node(node)
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
