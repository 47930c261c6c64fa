"""A real ROS 2 node in its own process that publishes ``/diagnostics``, steered through a file.

Run as ``python -m common.harness.diagpub '<json spec>'``::

    {"node": "battery_driver", "namespace": "/", "control": "/tmp/x.json", "rate": 10}

The control file holds ``{"seq": n, "statuses": [{"name", "level", "message",
"hardware_id", "values": {k: v}}], "rate": hz, "publish": true}``; the node
reads it whenever it changes (looked at every 20 ms), prints ``APPLIED <seq>``
and then publishes one ``DiagnosticArray`` of those statuses ``rate`` times a
second (``publish: false``: it stays in the graph but goes silent, as a hung
driver does).  ``{"burst": n}`` publishes n arrays at once (then goes on as
before).  Prints ``READY`` once its publisher exists, ``MATCHED`` once a subscriber (the
gateway) is matched.  Use :class:`DiagPub`.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile

from . import rosmain


def main() -> None:
    spec = json.loads(sys.argv[1])
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    node, stop = rosmain.start(spec["node"], namespace=spec.get("namespace", "/"))
    pub = node.create_publisher(DiagnosticArray, "/diagnostics", 100)
    state = {"mtime": None, "seq": -1, "msg": DiagnosticArray(), "publish": False, "rate": spec.get("rate", 10),
             "next": 0.0}

    def build(statuses: list[dict]) -> DiagnosticArray:
        msg = DiagnosticArray()
        for s in statuses:
            msg.status.append(DiagnosticStatus(
                level=bytes([int(s.get("level", 0))]), name=s["name"], message=s.get("message", ""),
                hardware_id=s.get("hardware_id", ""),
                values=[KeyValue(key=k, value=str(v)) for k, v in (s.get("values") or {}).items()]))
        return msg

    def look() -> None:
        try:
            mtime = os.stat(spec["control"]).st_mtime_ns
        except OSError:
            return
        if mtime == state["mtime"]:
            return
        state["mtime"] = mtime
        with open(spec["control"]) as fh:
            control = json.load(fh)
        if control.get("seq", 0) == state["seq"]:
            return
        state["seq"] = control.get("seq", 0)
        state["msg"] = build(control.get("statuses") or [])
        state["publish"] = bool(control.get("publish", True))
        state["rate"] = float(control.get("rate", state["rate"]))
        for _ in range(int(control.get("burst", 0))):
            pub.publish(state["msg"])
        print(f"APPLIED {state['seq']}", flush=True)

    def tick() -> None:
        if not state.get("matched") and pub.get_subscription_count() > 0:
            state["matched"] = True
            print("MATCHED", flush=True)  # a subscriber (the gateway) gets what is published from now on
        look()
        now = node.get_clock().now().nanoseconds / 1e9
        if state["publish"] and now >= state["next"]:
            state["next"] = now + 1.0 / state["rate"]
            stamped = state["msg"]
            stamped.header.stamp = node.get_clock().now().to_msg()
            pub.publish(stamped)

    node.create_timer(0.02, tick)
    print("READY", flush=True)
    rosmain.spin(node, stop)



def _write(path: str, control: dict) -> None:
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(path))
    with os.fdopen(fd, "w") as fh:
        json.dump(control, fh)
    os.replace(tmp, path)


class DiagPub:
    """The node above, from a test: ``set(statuses)`` and wait until it applied them."""

    def __init__(self, node: str, namespace: str = "/", rate: float = 10, timeout: float = 20.0,
                 env: dict | None = None):
        from .procs import Proc

        self.dir = tempfile.mkdtemp(prefix="diagpub-")
        self.control = os.path.join(self.dir, "control.json")
        self.seq = 0
        spec = {"node": node, "namespace": namespace, "control": self.control, "rate": rate}
        self.proc = Proc([sys.executable, "-m", "common.harness.diagpub", json.dumps(spec)], env=env, name=f"diagpub {node}")
        self.proc.wait_line(lambda line: line == "READY", timeout)

    def matched(self, timeout: float = 20.0) -> DiagPub:
        """Wait until a subscriber of /diagnostics (the gateway's) is matched: nothing published is lost."""
        self.proc.wait_line(lambda line: line == "MATCHED", timeout)
        return self

    def set(self, statuses: list[dict], publish: bool = True, rate: float | None = None, burst: int = 0,
            timeout: float = 10.0) -> None:
        self.seq += 1
        control: dict = {"seq": self.seq, "statuses": statuses, "publish": publish, "burst": burst}
        if rate is not None:
            control["rate"] = rate
        _write(self.control, control)
        self.proc.wait_line(lambda line, s=self.seq: line == f"APPLIED {s}", timeout)

    def stop(self) -> int:
        import shutil

        code = self.proc.stop()
        shutil.rmtree(self.dir, ignore_errors=True)
        return code


if __name__ == "__main__":
    main()
