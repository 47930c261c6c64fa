"""A real ROS 2 node in its own process, for tests: publishes and/or subscribes.

Run as ``python -m tests.support.rospub '<json spec>'``::

    {"node": "temp_sensor", "namespace": "/powertrain/engine",
     "publish": [{"topic": "temperature", "type": "sensor_msgs/msg/Temperature",
                  "rate": 10, "value": {"temperature": 93.5}, "counter": "variance",
                  "reliability": "reliable", "durability": "volatile", "depth": 10,
                  "once": false, "raw": null}],
     "subscribe": [{"topic": "cmd", "type": "std_msgs/msg/Float32", "echo": true,
                    "reliability": "reliable", "durability": "transient_local"}]}

Prints ``READY`` once every entity exists; with ``echo``, prints each received
message as one JSON line ``{"topic":..., "data": {...}}``.  ``counter`` names a
numeric field that is incremented on every publish so tests can tell samples
apart.  ``raw`` (hex) publishes those bytes as the serialized message instead,
for messages that do not deserialize.  SIGTERM destroys the node cleanly so
that it leaves the graph at once.

From a test: :class:`RosNode` (this program in another process), :func:`publisher` (one node, one
topic) and :func:`unique_topic`.
"""

from __future__ import annotations

import array
import importlib
import json
import sys
import uuid

from common.harness import rosmain
from common.harness.procs import Proc


def _load(type_name: str):
    pkg, _, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def _value(value):
    """JSON cannot carry ``bytes``: ``{"__bytes__": [1, 2]}`` becomes ``[b"\\x01", b"\\x02"]``;
    ``{"__fill__": [7, 921600]}`` is a uint8 array of 921600 sevens (an image, short enough for argv)."""
    if isinstance(value, dict) and "__bytes__" in value:
        return [bytes([b]) for b in value["__bytes__"]]
    if isinstance(value, dict) and "__fill__" in value:
        byte, count = value["__fill__"]
        return array.array("B", bytes([byte]) * count)
    return value


def _assign(msg, values: dict) -> None:
    for key, value in values.items():
        current = getattr(msg, key)
        if isinstance(value, dict) and "__bytes__" not in value and "__fill__" not in value:
            _assign(current, value)
        else:
            setattr(msg, key, _value(value))


def _plain(msg):
    if hasattr(msg, "get_fields_and_field_types"):
        return {k: _plain(getattr(msg, k)) for k in msg.get_fields_and_field_types()}
    if isinstance(msg, (list, tuple)):
        return [_plain(v) for v in msg]
    if hasattr(msg, "tolist"):
        return msg.tolist()
    if isinstance(msg, bytes):
        return list(msg)
    return msg


def _set_path(msg, path: str, value) -> None:
    *parents, leaf = path.split(".")
    for p in parents:
        msg = getattr(msg, p)
    current = getattr(msg, leaf)
    setattr(msg, leaf, type(current)(value))


def main() -> None:
    spec = json.loads(sys.argv[1])
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    node, stop = rosmain.start(spec["node"], namespace=spec.get("namespace", "/"))
    def qos(item):
        return QoSProfile(
            depth=item.get("depth", 10),
            reliability=(ReliabilityPolicy.BEST_EFFORT if item.get("reliability") == "best_effort"
                         else ReliabilityPolicy.RELIABLE),
            durability=(DurabilityPolicy.TRANSIENT_LOCAL if item.get("durability") == "transient_local"
                        else DurabilityPolicy.VOLATILE),
        )

    for item in spec.get("publish", []):
        cls = _load(item["type"])
        pub = node.create_publisher(cls, item["topic"], qos(item))
        if item.get("raw") is not None:
            msg = bytes.fromhex(item["raw"])
        else:
            msg = cls()
            _assign(msg, item.get("value", {}))
        state = {"n": 0}

        def tick(pub=pub, msg=msg, item=item, state=state):
            state["n"] += 1
            if item.get("counter"):
                _set_path(msg, item["counter"], state["n"])
            pub.publish(msg)

        if item.get("once") or not item.get("rate"):
            tick()
        else:
            node.create_timer(1.0 / float(item["rate"]), tick)

    for item in spec.get("subscribe", []):
        cls = _load(item["type"])
        topic = node.resolve_topic_name(item["topic"])
        echo = bool(item.get("echo", False))

        def on_msg(msg, topic=topic, echo=echo):
            if echo:
                print(json.dumps({"topic": topic, "data": _plain(msg)}), flush=True)

        node.create_subscription(cls, item["topic"], on_msg, qos(item))

    print("READY", flush=True)
    rosmain.spin(node, stop)


def unique_topic(name: str) -> str:
    """``/t<8 hex>/name``: a topic no other test (or earlier run in the same domain) uses."""
    return f"/t{uuid.uuid4().hex[:8]}/{name}"


class RosNode(Proc):
    """This program in another process: returns once it printed ``READY``."""

    def __init__(self, spec: dict, timeout: float = 20.0, env: dict | None = None):
        super().__init__([sys.executable, "-m", "tests.support.rospub", json.dumps(spec)], env=env,
                         name=f"rosnode {spec.get('node')}")
        self.wait_line(lambda line: line == "READY", timeout)

    def echoed(self) -> list[dict]:
        out = []
        for line in self.output:
            if line.startswith("{"):
                out.append(json.loads(line))
        return out


def publisher(node: str, topic: str, type_: str, value: dict | None = None, rate: float = 10,
              namespace: str = "/", **options) -> RosNode:
    """One node publishing one topic: the common case."""
    item = {"topic": topic, "type": type_, "rate": rate, "value": value or {}, **options}
    return RosNode({"node": node, "namespace": namespace, "publish": [item]})


if __name__ == "__main__":
    main()
