"""Managed (lifecycle) ROS 2 nodes in their own process, for the status tests.

Run as ``python -m tests.support.lifecyclenode '<json spec>'``::

    {"nodes": [{"name": "idle"},                          # a LifecycleNode left unconfigured
               {"name": "running", "activate": true},     # configured and activated at start
               {"name": "stuck", "hang": true}],          # GetState and ChangeState services that never answer
     "namespace": "/lc"}

A hanging node is a plain node that offers both lifecycle services, as medkit's
``unreadable_lifecycle_node.cpp`` does, and is never spun (its requests are never taken).
Each stdin line ``<name> <transition>`` (``configure``, ``activate``, ``deactivate``) drives that
node's own state machine and answers ``DONE <name> <state label>``.  Prints ``READY`` once every
node exists (and the active ones are active).
"""

from __future__ import annotations

import json
import sys
import threading

from common.harness import rosmain


def main() -> None:
    spec = json.loads(sys.argv[1])
    import rclpy
    from lifecycle_msgs.srv import ChangeState, GetState
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.lifecycle import LifecycleNode
    from rclpy.node import Node

    namespace = spec.get("namespace", "/")
    _, stop = rosmain.start(spec.get("host", "lifecycle_host"), namespace=namespace)
    executor = SingleThreadedExecutor()
    managed: dict[str, LifecycleNode] = {}
    hanging = []
    for item in spec["nodes"]:
        if item.get("hang"):
            node = Node(item["name"], namespace=namespace, context=rclpy.get_default_context())
            node.create_service(GetState, "~/get_state", lambda req, res: res)
            node.create_service(ChangeState, "~/change_state", lambda req, res: res)
            hanging.append(node)  # never added to the executor: nothing it receives is answered
            continue
        node = LifecycleNode(item["name"], namespace=namespace)
        if item.get("activate"):
            node.trigger_configure()
            node.trigger_activate()
        managed[item["name"]] = node
        executor.add_node(node)
    lock = threading.Lock()

    def commands() -> None:
        for line in sys.stdin:
            name, _, transition = line.strip().partition(" ")
            node = managed.get(name)
            if node is None:
                continue
            with lock:
                getattr(node, f"trigger_{transition}")()
                label = node._state_machine.current_state[1]
            print(f"DONE {name} {label}", flush=True)
        stop.set()

    threading.Thread(target=commands, daemon=True).start()
    print("READY", flush=True)
    try:
        while not stop.is_set():
            with lock:
                executor.spin_once(timeout_sec=0.05)
    finally:
        for node in [*managed.values(), *hanging]:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
