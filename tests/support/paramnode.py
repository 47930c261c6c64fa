"""A real ROS 2 node with parameters in its own process, for the configurations tests.

Run as ``python -m tests.support.paramnode '<json spec>'``::

    {"node": "tuner", "namespace": "/",
     "params": [{"name": "rate", "value": 10.0, "description": "Hz", "read_only": false,
                 "int_range": [0, 100, 1], "float_range": [0.0, 50.0, 0.0], "dynamic": false}],
     "overrides": {"extra": 5},        # with automatically_declare_parameters_from_overrides
     "refuse": {"mode": ["auto"]},     # values a set callback refuses ("<value> is locked")
     "declare_on": {"trigger": "arm", "name": "late", "value": 3},  # set arm true: late is declared
     "hang": false,                    # true: never runs a callback (its services never answer);
                                       # "until-usr1": none until SIGUSR1, then answers what waited
     "services": true,                 # false: no parameter services at all
     "count": 1}                       # n > 1: n nodes <node>_0 ... <node>_<n-1> in this one process,
                                       # each with "params" (and a parameter "index": its number)

A value ``{"__bytes__": [1, 2]}`` is a byte array.  Prints ``READY`` once the node
exists; SIGTERM destroys it so that it leaves the graph at once.

``python -m tests.support.paramnode --set /fqn name '<json value>'`` is another
client: it sets one parameter through the node's ``set_parameters`` service
(a bare rclpy client) and prints ``SET ok`` or ``SET failed <reason>``.
"""

from __future__ import annotations

import json
import signal
import sys
import threading
import time

from common.harness import rosmain


def _value(value):
    if isinstance(value, dict) and "__bytes__" in value:
        return [bytes([b]) for b in value["__bytes__"]]
    if isinstance(value, list):
        return [float(v) if v in ("NaN", "Infinity", "-Infinity") else v for v in value]
    if value in ("NaN", "Infinity", "-Infinity"):
        return float(value.replace("Infinity", "inf"))
    return value


def _descriptor(item: dict):
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

    d = ParameterDescriptor(description=item.get("description", ""), read_only=bool(item.get("read_only")),
                            dynamic_typing=bool(item.get("dynamic")))
    if item.get("int_range"):
        lo, hi, step = item["int_range"]
        d.integer_range = [IntegerRange(from_value=lo, to_value=hi, step=step)]
    if item.get("float_range"):
        lo, hi, step = item["float_range"]
        d.floating_point_range = [FloatingPointRange(from_value=lo, to_value=hi, step=step)]
    return d


def serve_many(spec: dict) -> None:
    """``count`` nodes with parameters in one process (one rclpy context, one executor)."""
    from rclpy.node import Node

    first, stop = rosmain.start(f"{spec['node']}_0", namespace=spec.get("namespace", "/"))
    nodes = [first] + [Node(f"{spec['node']}_{i}", namespace=spec.get("namespace", "/"))
                       for i in range(1, int(spec["count"]))]
    for i, node in enumerate(nodes):
        node.declare_parameter("index", i)
        for item in spec.get("params", []):
            node.declare_parameter(item["name"], _value(item["value"]), _descriptor(item))
    print("READY", flush=True)
    rosmain.spin(first, stop, nodes[1:])


def serve(spec: dict) -> None:
    from rclpy.parameter import Parameter

    if int(spec.get("count", 1)) > 1:
        serve_many(spec)
        return

    options = {"namespace": spec.get("namespace", "/"),
               "start_parameter_services": spec.get("services", True)}
    if spec.get("overrides"):
        options["parameter_overrides"] = [Parameter(k, value=_value(v)) for k, v in spec["overrides"].items()]
        options["automatically_declare_parameters_from_overrides"] = True
    node, stop = rosmain.start(spec["node"], **options)
    for item in spec.get("params", []):
        node.declare_parameter(item["name"], _value(item["value"]), _descriptor(item))
    refuse = spec.get("refuse") or {}
    if refuse:
        from rcl_interfaces.msg import SetParametersResult

        def check(params):
            for p in params:
                if p.value in refuse.get(p.name, []):
                    return SetParametersResult(successful=False, reason=f"{p.name} {p.value} is locked")
            return SetParametersResult(successful=True)

        node.add_on_set_parameters_callback(check)
    later = spec.get("declare_on")
    if later:
        armed = []
        node.declare_parameter(later["trigger"], False)
        node.add_post_set_parameters_callback(
            lambda params: armed.extend(p for p in params if p.name == later["trigger"] and p.value is True))

        def declare_when_armed():
            if armed and not node.has_parameter(later["name"]):
                node.declare_parameter(later["name"], _value(later["value"]))

        node.create_timer(0.05, declare_when_armed)
    print("READY", flush=True)
    if spec.get("hang") == "until-usr1":  # slow, not hung: the requests wait, then get their answers
        woken = threading.Event()
        signal.signal(signal.SIGUSR1, lambda *_: woken.set())
        while not stop.is_set() and not woken.is_set():
            time.sleep(0.05)
    elif spec.get("hang"):
        while not stop.is_set():  # in the graph, services and all, but nothing ever answers
            time.sleep(0.05)
        node.destroy_node()
        return
    rosmain.spin(node, stop)


def set_once(fqn: str, name: str, value) -> None:
    import rclpy
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    node, _ = rosmain.start("paramnode_setter")
    client = node.create_client(SetParameters, f"{fqn}/set_parameters")
    if not client.wait_for_service(timeout_sec=10):
        print("SET failed no service", flush=True)
        return
    future = client.call_async(SetParameters.Request(parameters=[Parameter(name, value=_value(value)).to_parameter_msg()]))
    rclpy.spin_until_future_complete(node, future, timeout_sec=10)
    result = future.result()
    if result is None:
        print("SET failed no answer", flush=True)
    elif result.results[0].successful:
        print("SET ok", flush=True)
    else:
        print("SET failed " + result.results[0].reason, flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


def main() -> None:
    if sys.argv[1] == "--set":
        set_once(sys.argv[2], sys.argv[3], json.loads(sys.argv[4]))
    else:
        serve(json.loads(sys.argv[1]))


if __name__ == "__main__":
    main()
