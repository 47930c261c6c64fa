"""Scenario 6, hostile IPC input in bulk (the single-frame cases are in test_rosworker_executor.py).

A burst of garbage frames of every kind the ROS worker must drop or refuse
(random bytes, msgpack nested deeper than the decoder allows, headers that
claim gigabytes, maps without ids, unknown commands, bad arguments, extra
frames, oversized frames), many short-lived peers that send one frame and
vanish without reading the answer, and a flood of queued commands that
nobody reads.  Afterwards the same ROS worker answers ``ping`` and real work
at once, its queue is empty, and its memory and file descriptors are bounded.
"""

from __future__ import annotations

import random
import time

import msgpack
import psutil
import zmq

from ipc import protocol
from tests.reliability.load import record, scaled
from tests.support.procs import poll_until
from tests.support.rosworker import RosWorker

GARBAGE = scaled(10_000, 100_000)
PEERS = scaled(300, 2000)
FLOOD = scaled(5_000, 50_000)
MAX_QUEUE = 64


def garbage(rng: random.Random, i: int) -> tuple[list[bytes], bool]:
    """One hostile message and whether the worker should drop it (True) or answer an error."""
    kind = i % 12
    if kind == 0:
        return [rng.randbytes(rng.randrange(1, 512))], True
    if kind == 1:
        return [b"\x91" * 5000 + b"\x01"], True                    # nested deeper than msgpack allows
    if kind == 2:
        return [b"\xdf\xff\xff\xff\xff"], True                     # a map claiming 4G entries
    if kind == 3:
        return [b"\xdb\xff\xff\xff\xff" + b"x" * 16], True         # a string claiming 4 GB
    if kind == 4:
        return [msgpack.packb(list(range(50)))], True              # not a map
    if kind == 5:
        return [msgpack.packb({"v": 1, "cmd": "ping", "id": 1.5})], True  # id not an int
    if kind == 6:
        return [msgpack.packb({"v": 1, "id": i, "cmd": "ping"}), b"extra"], True
    if kind == 7:
        return [msgpack.packb({"v": 1, "id": i, "cmd": "x" * 5000, "args": {}})], False
    if kind == 8:
        return [msgpack.packb({"v": 1, "id": i, "cmd": "sample", "args": {"topic": "/a\x00/../b" * 50},
                               "deadline_ms": 1000})], False
    if kind == 9:
        return [msgpack.packb({"v": 1, "id": i, "cmd": "publish", "deadline_ms": 1000,
                               "args": {"topic": "/x", "type": "os/msg/system", "data": {"a": [1] * 1000}}})], False
    if kind == 10:
        return [msgpack.packb({"v": 1, "id": i, "cmd": "graph", "args": {"since": "x" * 100},
                               "deadline_ms": 10**12})], False
    return [msgpack.packb({"v": 1, "id": i, "cmd": "type_info", "args": {"type": ["list"]},
                           "deadline_ms": 1000})], False


def test_bursts_of_hostile_frames_leave_the_worker_serving_and_bounded():
    worker = RosWorker(max_queue_depth=MAX_QUEUE)
    ctx = zmq.Context()
    proc = psutil.Process(worker.pid)
    try:
        worker.sample("/hostile_ipc/nobody")  # first real work: imports and caches are in place
        rss_before, fds_before = proc.memory_info().rss / 2**20, proc.num_fds()
        dropped_before = worker.stats()["details"]["ipc_dropped_frames"]
        endpoint = protocol.endpoint(worker.runtime_dir)
        rng = random.Random(6)
        started = time.monotonic()

        # 1. Garbage from a handful of peers that never read what comes back.
        expect_dropped = 0
        socks = []
        for _ in range(4):
            s = ctx.socket(zmq.DEALER)
            s.setsockopt(zmq.LINGER, 0)
            s.setsockopt(zmq.SNDHWM, 0)
            s.setsockopt(zmq.SNDTIMEO, 10_000)
            s.connect(endpoint)
            socks.append(s)
        for i in range(GARBAGE):
            frames, drop = garbage(rng, i)
            expect_dropped += drop
            socks[i % len(socks)].send_multipart(frames)
        # 2. Oversized frames: zmq drops the connection of a peer that sends one.
        for _ in range(3):
            big = ctx.socket(zmq.DEALER)
            big.setsockopt(zmq.LINGER, 2000)
            big.connect(endpoint)
            big.send(b"\x00" * (protocol.MAX_FRAME + 1024))
            big.close()
        # 3. Peers that send one request and vanish without reading the reply.
        for i in range(PEERS):
            s = ctx.socket(zmq.DEALER)
            s.setsockopt(zmq.LINGER, 100)
            s.connect(endpoint)
            s.send(protocol.pack({"v": 1, "id": i, "cmd": "pool", "args": {}, "deadline_ms": 1000}))
            s.close()
        # 4. A flood of queued commands nobody reads: the bounded queue answers backpressure.
        flood = ctx.socket(zmq.DEALER)
        flood.setsockopt(zmq.LINGER, 0)
        flood.setsockopt(zmq.SNDHWM, 0)
        flood.setsockopt(zmq.SNDTIMEO, 10_000)
        flood.connect(endpoint)
        for i in range(FLOOD):
            flood.send(protocol.pack({"v": 1, "id": i, "cmd": "sample", "deadline_ms": 5000,
                                      "args": {"topic": f"/hostile_ipc/t{i % 500}", "timeout_ms": 0}}))
        sent_for = time.monotonic() - started

        # The same worker answers at once, and its queue drains.
        asked = time.monotonic()
        assert worker.call("ping", timeout=10)["pid"] == worker.pid
        ping_after = time.monotonic() - asked
        # Every peer is served in turn: the garbage of the others may still be on its way in.
        poll_until(lambda: worker.stats()["details"]["ipc_dropped_frames"] - dropped_before >= expect_dropped,
                   60, interval=0.1, message=f"{expect_dropped} garbage frames dropped")
        poll_until(lambda: worker.stats()["executor"]["queue_depth"] == 0, 60, message="queue drained")
        stats = worker.stats()
        assert stats["executor"]["queue_max_depth_observed"] <= MAX_QUEUE
        assert stats["executor"]["queue_dropped"] > 0, "the flood never met the queue bound"
        assert worker.sample("/hostile_ipc/nobody")["status"] == "metadata_only"
        assert worker.call("type_info", {"type": "std_msgs/msg/String"})["type"] == "std_msgs/msg/String"
        assert worker.proc.poll() is None
        for s in [*socks, flood]:
            s.close()

        # Bounded: memory grows by little, descriptors come back once the peers are gone.
        time.sleep(1.0)
        rss_after = proc.memory_info().rss / 2**20
        poll_until(lambda: proc.num_fds() <= fds_before + 4, 30, interval=0.2,
                   message=f"descriptors back near {fds_before} (now {proc.num_fds()})")
        record("hostile IPC", requests=GARBAGE + PEERS + FLOOD + 3,
               statuses={"dropped": stats["details"]["ipc_dropped_frames"] - dropped_before,
                         "backpressure": stats["executor"]["queue_dropped"]},
               worst_ms=ping_after * 1000, restarts=0,
               rss_before={"rosworker": rss_before}, rss_after={"rosworker": rss_after},
               note=f"{GARBAGE} garbage frames, {PEERS} vanishing peers, {FLOOD} unread commands "
                    f"sent in {sent_for:.1f} s; worst = ping right after")
        assert rss_after - rss_before < 64, f"RSS grew from {rss_before:.1f} to {rss_after:.1f} MB"
    finally:
        ctx.destroy(linger=0)
        worker.stop()
