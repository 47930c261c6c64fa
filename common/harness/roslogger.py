"""A real rclpy node that writes log lines to /rosout when told (tests of the logs, the bench).

``python -m common.harness.roslogger '{"node": "n", "namespace": "/"}'`` prints ``READY``,
then reads one JSON command per line on stdin and prints ``DONE <n>`` after each:

- ``{"log": [["warning", "text"], ...]}``: one line each, at that level;
- ``{"storm": {"hz": 10000, "seconds": 3, "level": "info"}}``: lines at that rate (as close as
  the process can; ``n`` is how many it wrote), published as ``rcl_interfaces/msg/Log`` on
  /rosout with rosout's QoS and this node's logger name (what rcl sends, without the cost
  of formatting each line in Python, so that one process reaches 10 kHz).
"""

from __future__ import annotations

import json
import os
import queue
import subprocess
import sys
import threading
import time

from .procs import REPO, Proc


def main() -> int:
    spec = json.loads(sys.argv[1])
    import rclpy
    from rclpy.node import Node

    rclpy.init(args=["--ros-args", "--disable-stdout-logs"])  # /rosout only: stdout is the command channel
    node = Node(spec["node"], namespace=spec.get("namespace", "/"))
    logger = node.get_logger()
    from rclpy.logging import LoggingSeverity

    logger.set_level(LoggingSeverity.DEBUG)
    # One call site (line) per level: rclpy refuses a call site whose severity changes.
    write = {
        "debug": lambda text: logger.debug(text),
        "info": lambda text: logger.info(text),
        "warning": lambda text: logger.warning(text),
        "error": lambda text: logger.error(text),
        "fatal": lambda text: logger.fatal(text),
    }
    print("READY", flush=True)
    for line in sys.stdin:
        command = json.loads(line)
        count = 0
        if "log" in command:
            for level, text in command["log"]:
                write[level](text)
                count += 1
        elif "storm" in command:
            storm = command["storm"]
            emit = flood(node, storm.get("level", "info"))
            period = 1.0 / storm["hz"]
            start = time.monotonic()
            end = start + storm["seconds"]
            while (now := time.monotonic()) < end:
                due = int((now - start) / period) + 1
                while count < due:
                    emit(f"storm line {count}")
                    count += 1
                time.sleep(0.001)
        print(f"DONE {count}", flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def flood(node, level: str):
    """A function that publishes one /rosout line of ``node`` at ``level`` (the storm's writer)."""
    from rcl_interfaces.msg import Log
    from rclpy.duration import Duration
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    profile = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL, lifespan=Duration(seconds=10))
    pub = node.create_publisher(Log, "/rosout", profile)
    msg = Log(level={"debug": 10, "info": 20, "warning": 30, "error": 40, "fatal": 50}[level],
              name=node.get_logger().name, file=__file__, function="flood", line=1)
    clock = node.get_clock()

    def emit(text: str) -> None:
        msg.stamp = clock.now().to_msg()
        msg.msg = text
        pub.publish(msg)
    return emit


class LoggerNode(Proc):
    """This module's node in another process, told what to log through its stdin."""

    def __init__(self, node: str, namespace: str = "/", timeout: float = 20.0):
        self.name = f"roslogger {node}"
        self.lines: queue.Queue[str] = queue.Queue()
        self.output: list[str] = []
        self.log_path = None
        self._log = None
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "common.harness.roslogger", json.dumps({"node": node, "namespace": namespace})],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.PIPE, text=True,
            env=dict(os.environ), cwd=REPO, start_new_session=True)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self.wait_line(lambda line: line == "READY", timeout)

    def _send(self, command: dict, timeout: float) -> int:
        self.proc.stdin.write(json.dumps(command) + "\n")
        self.proc.stdin.flush()
        return int(self.wait_line(lambda line: line.startswith("DONE "), timeout).split()[1])

    def log(self, *lines: tuple[str, str], timeout: float = 20.0) -> int:
        """Write these (level, text) lines; returns when they are written."""
        return self._send({"log": [list(line) for line in lines]}, timeout)

    def storm(self, hz: float, seconds: float, level: str = "info") -> int:
        """Write lines at ``hz`` for ``seconds``; how many were written."""
        return self._send({"storm": {"hz": hz, "seconds": seconds, "level": level}}, seconds + 30)

    def stop(self, timeout: float = 10.0) -> int:
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        return super().stop(timeout)


if __name__ == "__main__":
    sys.exit(main())
