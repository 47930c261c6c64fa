"""The fleet's processes for tests (issue 34): a Zenoh router, robots' gateways, the fleet gateway.

- :class:`Router`: ``sovd-zenoh-router`` on a free loopback port (``ready <zid>`` once it listens).
- :class:`FleetGateway`: ``sovd-gateway --fleet-aggregate``; healthy once ``/health`` says its fleet
  link answers (it has no ROS worker to wait for).
- :class:`SimFleet`: ``bench/fleetsim.py``'s simulated robots, steered line by line.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import requests

from .gateway import Gateway
from .procs import Proc, free_port

BIN = Path(sys.executable).parent
TOKEN = "fleet-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


class Router(Proc):
    def __init__(self, *args: str, scheme: str = "tcp", host: str = "127.0.0.1"):
        self.port = free_port()
        self.endpoint = f"{scheme}/{host}:{self.port}"
        super().__init__([str(BIN / "sovd-zenoh-router"), "--listen", self.endpoint, *args], name="zenoh router")
        self.wait_line(lambda line: line.startswith("ready "), 30)


class FleetGateway(Gateway):
    def _healthy(self) -> bool:
        if self.proc.poll() is not None:
            raise AssertionError(f"sovd-gateway exited with {self.proc.returncode}:\n" + self.tail(60))
        r = requests.get(self.api + "/health", timeout=2)
        return r.status_code == 200 and r.json()["x-medkit-fleet"]["link_alive"]

    def fleet_link(self):
        """The fleet-link process (the child that stands where a ROS worker would)."""
        for p in self._children():
            if any("fleetlink" in part for part in p.cmdline()):
                return p
        raise RuntimeError("no fleet link under the gateway")


class SimFleet(Proc):
    """Simulated robots (``bench/fleetsim.py``) on ``router``; ``answers`` as :func:`bench.fleetsim.record` makes."""

    def __init__(self, router: Router, answers: dict, robots: int, **spec):
        self.answers_file = tempfile.NamedTemporaryFile("w", suffix=".json", delete=False)  # noqa: SIM115
        json.dump(answers, self.answers_file)
        self.answers_file.close()
        full = {"connect": router.endpoint, "robots": robots, "answers": self.answers_file.name, **spec}
        super().__init__([sys.executable, "-m", "bench.fleetsim", json.dumps(full)], name="fleet simulator",
                         stdin=subprocess.PIPE)
        self.wait_line(lambda line: line == "READY", 60)

    def send(self, command: str, timeout: float = 10.0) -> None:
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()
        self.wait_line(lambda line: line in (f"OK {command}",) or line.startswith(f"ERROR {command}"), timeout)
