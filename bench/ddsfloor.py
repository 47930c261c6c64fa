"""The DDS floor of the idle-cost case: subscriptions that are held but never spun.

Run as ``python -m bench.ddsfloor '<json list of topics>'`` (by ``make bench``).  Waits until
every topic has a publisher, subscribes to each with the pool's QoS rules
(keep_last 1, matched reliability/durability), prints ``READY`` and then does
nothing but sleep until SIGTERM.  Whatever CPU this process uses is the cost
of the middleware delivering the messages into the readers' histories: the
least any process holding those subscriptions can cost.
"""

from __future__ import annotations

import json
import sys
import time

from common.harness import rosmain


def main() -> int:
    topics = json.loads(sys.argv[1])
    from rosworker.ros import msgtypes, qos

    node, stop = rosmain.start("bench_dds_floor", start_parameter_services=False, enable_rosout=False)
    deadline = time.monotonic() + 60
    for topic in topics:
        infos = rosmain.wait_for_publishers(node, topic, deadline - time.monotonic(), stop)
        if not infos:
            print(f"no publisher on {topic}", flush=True)
            return 1
        cls = msgtypes.load_type(infos[0].topic_type)
        node.create_subscription(cls, topic, lambda _m: None, qos.match_qos(infos))
    return rosmain.hold(node, stop)


if __name__ == "__main__":
    sys.exit(main())
