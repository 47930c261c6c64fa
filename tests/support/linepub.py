"""A real ROS 2 publisher whose every message the test chooses: one JSON line on stdin, one message.

Run as ``python -m tests.support.linepub <node> <topic> <type>`` (what
:class:`LinePublisher` does).  Each stdin line is a command:

- ``{"data": 1.5}``: the fields of one message, published at once; answers ``SENT <n>``;
- ``subs``: answers ``SUBS <count>`` (the topic's matched subscriptions).

NaN and infinities travel as Python's JSON writes them (``NaN``, ``Infinity``).
The publisher is reliable with a deep queue, so a subscriber that matched
gets every message.
"""

from __future__ import annotations

import json
import queue
import subprocess
import sys
import threading

from common.harness import rosmain
from common.harness.procs import REPO, Proc, poll_until

from .rospub import _assign, _load


def main() -> None:
    name, topic, type_name = sys.argv[1:4]
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    node, stop = rosmain.start(name)
    cls = _load(type_name)
    pub = node.create_publisher(cls, topic, QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
    sent = 0

    def serve() -> None:
        nonlocal sent
        for line in sys.stdin:
            line = line.strip()
            if line == "subs":
                print(f"SUBS {pub.get_subscription_count()}", flush=True)
            elif line:
                msg = cls()
                _assign(msg, json.loads(line))
                pub.publish(msg)
                sent += 1
                print(f"SENT {sent}", flush=True)
        stop.set()

    threading.Thread(target=serve, daemon=True).start()
    print("READY", flush=True)
    rosmain.spin(node, stop)


class LinePublisher(Proc):
    """The publisher above in its own process (a :class:`Proc` whose stdin is a pipe)."""

    def __init__(self, node: str, topic: str, type_name: str, timeout: float = 30.0):
        self.topic = topic
        # Proc's fields, with a stdin pipe (Proc gives its children none).
        self.name, self.log_path, self._log = f"linepub {node}", None, None
        self.lines: queue.Queue[str] = queue.Queue()
        self.output: list[str] = []
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tests.support.linepub", node, topic, type_name], stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=REPO, start_new_session=True)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self.wait_line(lambda line: line == "READY", timeout)

    def _command(self, line: str, answer: str, timeout: float) -> str:
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        return self.wait_line(lambda out: out.startswith(answer), timeout)

    def send(self, fields: dict, timeout: float = 10.0) -> None:
        """Publish one message with ``fields`` (returns once it is published)."""
        self._command(json.dumps(fields), "SENT ", timeout)

    def subscribers(self) -> int:
        return int(self._command("subs", "SUBS ", 10).split()[1])

    def wait_subscribers(self, count: int, timeout: float = 20.0) -> None:
        poll_until(lambda: self.subscribers() >= count, timeout, interval=0.05,
                   message=f"{count} subscriptions of {self.topic}")


if __name__ == "__main__":
    main()
