"""Publishers for the bench: many topics in one node, one timer per group.

Run as ``python -m bench.benchpub '<json spec>'``::

    {"node": "bench_idle",
     "groups": [{"prefix": "/bench/idle/t", "count": 50, "rate": 100, "kind": "small"},
                {"topic": "/bench/camera/image", "rate": 10, "kind": "image"}]}

``kind``: ``small`` (``sensor_msgs/msg/Temperature``) or ``image``
(``sensor_msgs/msg/Image``, 640×480 ``rgb8``).  A group publishes all of its
topics from one timer, so 50 topics at 100 Hz cost 100 callbacks a second,
not 5,000: the publishing process stays light and leaves the CPU to what is
measured.  Every publish carries a fresh stamp (a new message each time).

QoS: reliable, volatile, depth 1 (what a sensor driver would use).  Prints
``READY`` once every publisher exists; SIGTERM destroys the node and exits.
"""

from __future__ import annotations

import array
import json
import sys

from common.harness import rosmain

IMAGE_WIDTH, IMAGE_HEIGHT = 640, 480


def _topics(group: dict) -> list[str]:
    if "topic" in group:
        return [group["topic"]]
    return [f"{group['prefix']}{i}" for i in range(int(group["count"]))]


def main() -> None:
    spec = json.loads(sys.argv[1])
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image, Temperature

    node, stop = rosmain.start(spec["node"], start_parameter_services=False, enable_rosout=False)
    qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.VOLATILE)
    clock = node.get_clock()

    for group in spec["groups"]:
        kind = group.get("kind", "small")
        if kind == "image":
            msg = Image(height=IMAGE_HEIGHT, width=IMAGE_WIDTH, encoding="rgb8", step=IMAGE_WIDTH * 3)
            msg.header.frame_id = "camera"
            msg.data = array.array("B", bytes(i % 251 for i in range(IMAGE_WIDTH * IMAGE_HEIGHT * 3)))
            cls = Image
        else:
            msg = Temperature(temperature=21.5, variance=0.25)
            msg.header.frame_id = "bench"
            cls = Temperature
        pubs = [node.create_publisher(cls, t, qos) for t in _topics(group)]

        def tick(pubs=pubs, msg=msg):
            msg.header.stamp = clock.now().to_msg()
            for pub in pubs:
                pub.publish(msg)

        node.create_timer(1.0 / float(group["rate"]), tick)

    print("READY", flush=True)
    rosmain.spin(node, stop)


if __name__ == "__main__":
    main()
