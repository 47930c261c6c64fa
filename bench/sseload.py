"""Many SSE streams read by one process, for the bench and the reliability suite.

Run as ``python -m bench.sseload '<json spec>'``::

    {"port": 8080, "paths": ["/api/v1/apps/x/cyclic-subscriptions/sub_.../events", ...],
     "period": 0.2, "open_for": 30, "measure_from": 5, "connect_rate": 400,
     "stamp_field": null}

Opens every stream (at most ``connect_rate`` per second), reads them all with
one selector, and prints one JSON line when done::

    {"opened": N, "failed": N, "events": N, "errors": N, "window_s": ...,
     "delivered": N, "expected": N, "lateness_ms": {"p50", "p99", "max"},
     "per_stream_min": N, "cpu_s": ..., "stamp_latency_ms": {...}}

Lateness of a frame: when its last byte arrived, minus the slot of the fixed
``period`` grid its envelope timestamp falls on (a late tick counts as
lateness, and a skipped one as a frame not delivered).  The grid is each
stream's own, from its first frame: the ROS worker phases each topic's ticks
to its messages' arrivals (issue 23), so two topics' grids differ.  ``delivered``/``expected`` count frames whose slot lies in the
measurement window ``[measure_from, open_for]`` seconds after the start.
With ``stamp_field`` (e.g. ``"header.stamp"``), the latency from that stamp
in the payload (a publisher's clock) to arrival is measured too, once per new
stamp per stream.
"""

from __future__ import annotations

import json
import re
import resource
import selectors
import socket
import statistics
import sys
import time
from datetime import datetime

STAMP = re.compile(rb'^data: \{"timestamp":"([^"]+)"')


def _ms(text: bytes) -> float:
    """RFC 3339 ``2026-02-14T10:30:00.250Z`` -> ms since the epoch."""
    return datetime.fromisoformat(text.decode().replace("Z", "+00:00")).timestamp() * 1000


class Reader:
    __slots__ = ("sock", "buf", "head_done", "chunked", "pending", "events", "slots", "stamps", "last_stamp",
                 "grid")

    def __init__(self, sock: socket.socket):
        self.sock = sock
        self.buf = b""
        self.head_done = False
        self.chunked = False
        self.pending = b""      # de-chunked body not yet split into events
        self.events = 0
        self.slots: set[int] = set()
        self.stamps: list[float] = []
        self.last_stamp = None
        self.grid: float | None = None   # ms: the envelope stamp of this stream's first frame


def _percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    values = sorted(values)
    return values[min(len(values) - 1, int(round(q * (len(values) - 1))))]


def main() -> None:
    spec = json.loads(sys.argv[1])
    port, paths, period = spec["port"], spec["paths"], spec["period"]
    open_for, measure_from = spec["open_for"], spec["measure_from"]
    stamp_field = spec.get("stamp_field")
    period_ms = period * 1000
    selector = selectors.DefaultSelector()
    readers: list[Reader] = []
    lateness: list[float] = []
    stamp_latency: list[float] = []
    stamp_to_tick: list[float] = []   # publish stamp -> the tick that took it: the cyclic design's wait
    failed = errors = 0
    started = time.time()
    window_start = started + measure_from
    window_end = started + open_for
    gap = 1.0 / spec.get("connect_rate", 400)

    def connect(path: str) -> None:
        nonlocal failed
        try:
            sock = socket.create_connection(("127.0.0.1", port), timeout=10)
            sock.sendall(f"GET {path} HTTP/1.1\r\nHost: x\r\nAccept: text/event-stream\r\n\r\n".encode())
            sock.setblocking(False)
        except OSError:
            failed += 1
            return
        reader = Reader(sock)
        readers.append(reader)
        selector.register(sock, selectors.EVENT_READ, reader)

    def on_event(reader: Reader, block: bytes, arrived_ms: float) -> None:
        nonlocal errors
        match = STAMP.match(block)
        if not match:
            return
        reader.events += 1
        if b'"error":' in block[:80]:
            errors += 1
            return
        stamp = _ms(match.group(1))
        if reader.grid is None:
            reader.grid = stamp
        slot = round((stamp - reader.grid) / period_ms)
        scheduled = reader.grid + slot * period_ms
        if window_start * 1000 <= scheduled <= window_end * 1000:
            reader.slots.add(slot)
            lateness.append(arrived_ms - scheduled)
        if stamp_field:
            doc = json.loads(block[6:])
            value = doc.get("payload", {}).get("data", {})
            for part in stamp_field.split("."):
                value = value.get(part, {}) if isinstance(value, dict) else {}
            if isinstance(value, dict) and "sec" in value:
                pub_ms = value["sec"] * 1000 + value["nanosec"] / 1e6
                if pub_ms != reader.last_stamp and window_start * 1000 <= arrived_ms <= window_end * 1000:
                    reader.last_stamp = pub_ms
                    stamp_latency.append(arrived_ms - pub_ms)
                    stamp_to_tick.append(stamp - pub_ms)

    def feed(reader: Reader, data: bytes) -> None:
        reader.buf += data
        if not reader.head_done:
            if b"\r\n\r\n" not in reader.buf:
                return
            head, _, reader.buf = reader.buf.partition(b"\r\n\r\n")
            reader.head_done = True
            reader.chunked = b"chunked" in head.lower()
            if not head.startswith(b"HTTP/1.1 200"):
                raise ConnectionError(head[:100])
        if reader.chunked:
            while True:
                size_line, sep, rest = reader.buf.partition(b"\r\n")
                if not sep:
                    break
                size = int(size_line.split(b";")[0], 16)
                if len(rest) < size + 2:
                    break
                reader.pending += rest[:size]
                reader.buf = rest[size + 2:]
                if size == 0:
                    break
        else:
            reader.pending += reader.buf
            reader.buf = b""
        arrived_ms = time.time() * 1000
        while b"\n\n" in reader.pending:
            block, _, reader.pending = reader.pending.partition(b"\n\n")
            on_event(reader, block, arrived_ms)

    queue = list(paths)
    next_connect = time.monotonic()
    while time.time() < window_end:
        now = time.monotonic()
        while queue and now >= next_connect:
            connect(queue.pop())
            next_connect += gap
        timeout = 0.05 if queue else max(0.0, min(0.2, window_end - time.time()))
        for key, _ in selector.select(timeout=timeout):
            reader = key.data
            try:
                data = reader.sock.recv(262144)
                if not data:
                    raise ConnectionError("closed")
                feed(reader, data)
            except BlockingIOError:
                continue
            except (OSError, ValueError):
                selector.unregister(reader.sock)
                reader.sock.close()
                failed += 1
    for reader in readers:
        try:
            reader.sock.close()
        except OSError:
            pass
    slots_per_stream = max(0, int((window_end - window_start) * 1000 / period_ms))
    usage = resource.getrusage(resource.RUSAGE_SELF)
    print(json.dumps({
        "opened": len(readers), "failed": failed, "errors": errors,
        "events": sum(r.events for r in readers), "window_s": window_end - window_start,
        "delivered": sum(len(r.slots) for r in readers), "expected": slots_per_stream * len(readers),
        "per_stream_min": min((len(r.slots) for r in readers), default=0),
        "lateness_ms": {"p50": _percentile(lateness, 0.5), "p99": _percentile(lateness, 0.99),
                        "max": max(lateness, default=float("nan")),
                        "mean": statistics.fmean(lateness) if lateness else float("nan")},
        "stamp_latency_ms": {"p50": _percentile(stamp_latency, 0.5), "p99": _percentile(stamp_latency, 0.99),
                             "n": len(stamp_latency)},
        "stamp_to_tick_ms": {"p50": _percentile(stamp_to_tick, 0.5), "n": len(stamp_to_tick)},
        "cpu_s": usage.ru_utime + usage.ru_stime,
    }), flush=True)


if __name__ == "__main__":
    main()
