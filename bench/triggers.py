"""The triggers' bench row: an ``OnChange`` trigger per client on a 100 Hz topic, beside a bare rclpy subscriber.

Run as ``python -m bench.triggers [--seconds 20] [--clients 100] [--shared]``.  A publisher
(``bench/benchpub.py``, ``sensor_msgs/msg/Temperature`` at 100 Hz, a fresh
``header.stamp`` each message) feeds a gateway; each of ``--clients`` clients
makes its own ``OnChange`` trigger on ``/header/stamp`` (it changes on every
message; ``--shared``: one trigger that every client streams) and reads its event stream (two reader processes, raw sockets).  In
the same run a bare rclpy subscriber on the same topic is the reference.

Measured, from the messages stamped inside the measuring window: delivered
(events received over messages the reference received, times the clients),
and latency (receive time minus ``header.stamp``, both the wall clock of this
machine) p50 and p99, for the streams and for the reference.  One JSON line.
"""

from __future__ import annotations

import argparse
import json
import selectors
import socket
import statistics
import sys
import time

APP, TOPIC = "bench_trigger_pub", "/bench/trigger/t0"
RATE = 100


def _pct(values: list[float], q: float) -> float | None:
    if not values:
        return None
    values = sorted(values)
    return values[min(len(values) - 1, int(q * len(values)))]


def _stamp(payload: dict) -> float:
    stamp = payload["header"]["stamp"]
    return stamp["sec"] + stamp["nanosec"] / 1e9


def reader(spec: dict) -> None:
    """Read SSE streams (raw sockets, one selector) until ``until``; latencies of events stamped in the window."""
    import orjson

    sel = selectors.DefaultSelector()
    for path in spec["paths"]:
        sock = socket.create_connection(("127.0.0.1", spec["port"]))
        sock.sendall(f"GET {path} HTTP/1.1\r\nHost: x\r\nAccept: text/event-stream\r\n\r\n".encode())
        sock.setblocking(False)
        sel.register(sock, selectors.EVENT_READ, [b""])
    lat, events, window = [], 0, (spec["from"], spec["to"])
    while time.time() < spec["until"]:
        for key, _ in sel.select(0.2):
            try:
                data = key.fileobj.recv(65536)
            except BlockingIOError:
                continue
            if not data:
                sel.unregister(key.fileobj)
                continue
            now = time.time()
            buf = key.data[0] + data
            lines = buf.split(b"\n")
            key.data[0] = lines.pop()
            for line in lines:
                if line.startswith(b"data: "):
                    stamp = _stamp(orjson.loads(line[6:])["payload"])
                    if window[0] <= stamp < window[1]:
                        events += 1
                        lat.append((now - stamp) * 1000)
    print(json.dumps({"events": events, "latencies": lat}), flush=True)


def reference(spec: dict) -> None:
    """A bare rclpy subscriber: what the middleware alone delivers, and how late."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Temperature

    from common.harness import rosmain

    node, stop = rosmain.start("bench_trigger_reference")
    lat: list[float] = []

    def on_msg(msg) -> None:
        now = time.time()
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec / 1e9
        if spec["from"] <= stamp < spec["to"]:
            lat.append((now - stamp) * 1000)

    node.create_subscription(Temperature, TOPIC, on_msg, QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    print("READY", flush=True)
    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor()
    executor.add_node(node)
    while time.time() < spec["until"] and not stop.is_set():
        executor.spin_once(timeout_sec=0.05)
    print(json.dumps({"events": len(lat), "latencies": lat}), flush=True)


def main(argv: list[str] | None = None) -> int:
    from common.harness.gateway import Gateway
    from common.harness.procs import Proc, poll_until

    parser = argparse.ArgumentParser(prog="python -m bench.triggers")
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--clients", type=int, default=100)
    parser.add_argument("--shared", action="store_true", help="one trigger, every client streams it")
    args = parser.parse_args(argv)
    pub = Proc([sys.executable, "-m", "bench.benchpub", json.dumps(
        {"node": APP, "groups": [{"prefix": "/bench/trigger/t", "count": 1, "rate": RATE, "kind": "small"}]})],
        name="benchpub")
    pub.wait_line(lambda s: s == "READY", 60)
    gw = Gateway("--workers", "2", "--log-level", "warning", "--max-triggers-per-client", str(args.clients))
    procs = []
    try:
        poll_until(lambda: gw.get(f"/apps/{APP}").status_code == 200, 60, message="the publisher's app")
        import requests

        triggers = []
        for _ in range(1 if args.shared else args.clients):
            r = requests.post(f"{gw.api}/apps/{APP}/triggers", timeout=10, json={
                "resource": f"/api/v1/apps/{APP}/data{TOPIC}", "path": "/header/stamp", "multishot": True,
                "trigger_condition": {"condition_type": "OnChange"}})
            r.raise_for_status()
            triggers.append(r.json()["event_source"])
        triggers = (triggers * args.clients)[:args.clients]
        start = time.time() + 5.0            # streams open and settle first
        window = {"from": start, "to": start + args.seconds, "until": start + args.seconds + 3.0}
        ref = Proc([sys.executable, "-m", "bench.triggers", "reference", json.dumps(window)], name="reference")
        ref.wait_line(lambda s: s == "READY", 60)
        procs.append(ref)
        for i in range(2):
            spec = {**window, "port": gw.port, "paths": triggers[i::2]}
            procs.append(Proc([sys.executable, "-m", "bench.triggers", "reader", json.dumps(spec)], name=f"reader{i}"))
        outs = [json.loads(p.wait_line(lambda s: s.startswith("{"), args.seconds + 60)) for p in procs]
        health = gw.get("/health").json()["x-medkit-streams"]
    finally:
        for p in procs:
            p.stop()
        gw.stop()
        pub.stop()
    ref_out, streams = outs[0], outs[1:]
    lat = [x for o in streams for x in o["latencies"]]
    result = {
        "case": "trigger OnChange, 100 Hz topic", "clients": args.clients,
        "triggers": 1 if args.shared else args.clients, "seconds": args.seconds,
        "reference_messages": ref_out["events"], "events": sum(o["events"] for o in streams),
        "delivered": (sum(o["events"] for o in streams) / (ref_out["events"] * args.clients)
                      if ref_out["events"] else None),
        "p50_ms": _pct(lat, 0.5), "p99_ms": _pct(lat, 0.99),
        "reference_p50_ms": _pct(ref_out["latencies"], 0.5), "reference_p99_ms": _pct(ref_out["latencies"], 0.99),
        "frames_dropped": health["frames_dropped"], "trigger_messages": health["trigger_messages"],
        "mean_ms": statistics.fmean(lat) if lat else None,
    }
    print(json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] in ("reader", "reference"):
        (reader if sys.argv[1] == "reader" else reference)(json.loads(sys.argv[2]))
    else:
        sys.exit(main())
