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

from common.harness.procs import poll_until
from ipc import protocol
from tests.reliability.load import record, scaled
from tests.support.rosworker import RosWorker

GARBAGE = scaled(10_000, 30_000)
PEERS = scaled(300, 1000)
FLOOD = scaled(5_000, 20_000)
MAX_QUEUE = 64
BURSTS = scaled(3, 10)


# What becomes of each kind of hostile message: dropped unread, answered with an error by the
# IPC front, or queued for the ROS thread (which answers an error, or backpressure when full).
DROP, ANSWER, QUEUE = "drop", "answer", "queue"


def garbage(rng: random.Random, i: int) -> tuple[list[bytes], str]:
    """One hostile message and what the worker should do with it."""
    kind = i % 12
    if kind == 0:
        return [rng.randbytes(rng.randrange(1, 512))], DROP
    if kind == 1:
        return [b"\x91" * 5000 + b"\x01"], DROP                    # nested deeper than msgpack allows
    if kind == 2:
        return [b"\xdf\xff\xff\xff\xff"], DROP                     # a map claiming 4G entries
    if kind == 3:
        return [b"\xdb\xff\xff\xff\xff" + b"x" * 16], DROP         # a string claiming 4 GB
    if kind == 4:
        return [msgpack.packb(list(range(50)))], DROP              # not a map
    if kind == 5:
        return [msgpack.packb({"v": 1, "cmd": "ping", "id": 1.5})], DROP  # id not an int
    if kind == 6:
        return [msgpack.packb({"v": 1, "id": i, "cmd": "ping"}), b"extra"], DROP
    if kind == 7:
        return [msgpack.packb({"v": 1, "id": i, "cmd": "x" * 5000, "args": {}})], ANSWER
    if kind == 8:
        return [msgpack.packb({"v": 1, "id": i, "cmd": "sample", "args": {"topic": "/a\x00/../b" * 50},
                               "deadline_ms": 1000})], QUEUE
    if kind == 9:
        return [msgpack.packb({"v": 1, "id": i, "cmd": "publish", "deadline_ms": 1000,
                               "args": {"topic": "/x", "type": "os/msg/system", "data": {"a": [1] * 1000}}})], QUEUE
    if kind == 10:
        return [msgpack.packb({"v": 1, "id": i, "cmd": "graph", "args": {"since": "x" * 100},
                               "deadline_ms": 10**12})], ANSWER
    return [msgpack.packb({"v": 1, "id": i, "cmd": "type_info", "args": {"type": ["list"]},
                           "deadline_ms": 1000})], QUEUE


def burst(ctx: zmq.Context, endpoint: str, rng: random.Random) -> tuple[int, int, list[zmq.Socket]]:
    """One burst of every kind of hostile input.

    Returns (frames that should be dropped, commands that should reach the queue, sockets to close).
    """
    expect_dropped = expect_queued = 0
    # 1. Garbage from a handful of peers that never read what comes back.
    socks = []
    for _ in range(4):
        s = ctx.socket(zmq.DEALER)
        s.setsockopt(zmq.LINGER, 0)
        s.setsockopt(zmq.SNDHWM, 0)
        s.setsockopt(zmq.SNDTIMEO, 10_000)
        s.connect(endpoint)
        socks.append(s)
    for i in range(GARBAGE):
        frames, fate = garbage(rng, i)
        expect_dropped += fate == DROP
        expect_queued += fate == QUEUE
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
        s.setsockopt(zmq.LINGER, 5000)  # close() returns at once; the frame is still delivered
        s.connect(endpoint)
        s.send(protocol.pack({"v": 1, "id": i, "cmd": "pool", "args": {}, "deadline_ms": 1000}))
        s.close()
    expect_queued += PEERS
    # 4. A flood of queued commands nobody reads: the bounded queue answers backpressure.
    flood = ctx.socket(zmq.DEALER)
    flood.setsockopt(zmq.LINGER, 0)
    flood.setsockopt(zmq.SNDHWM, 0)
    flood.setsockopt(zmq.SNDTIMEO, 10_000)
    flood.connect(endpoint)
    for i in range(FLOOD):
        flood.send(protocol.pack({"v": 1, "id": i, "cmd": "sample", "deadline_ms": 5000,
                                  "args": {"topic": f"/hostile_ipc/t{i % 500}", "timeout_ms": 0}}))
    socks.append(flood)
    return expect_dropped, expect_queued + FLOOD, socks


def queue_outcomes(stats: dict) -> int:
    """Commands that left the queue (run, whatever their answer) or never got in (backpressure)."""
    ran = sum(c["count"] for c in stats["details"]["commands"].values())
    return ran + stats["executor"]["queue_dropped"]


def test_bursts_of_hostile_frames_leave_the_worker_serving_and_bounded():
    worker = RosWorker(max_queue_depth=MAX_QUEUE)
    ctx = zmq.Context()
    proc = psutil.Process(worker.pid)
    rss = lambda: proc.memory_info().rss / 2**20  # noqa: E731
    try:
        worker.sample("/hostile_ipc/nobody")  # first real work: imports and caches are in place
        rss_before, fds_before = rss(), proc.num_fds()
        endpoint = protocol.endpoint(worker.runtime_dir)
        rng = random.Random(6)
        rss_after_burst, pings = [], []
        sent = 0
        for _ in range(BURSTS):
            stats_before = worker.stats()
            dropped_before = stats_before["details"]["ipc_dropped_frames"]
            outcomes_before = queue_outcomes(stats_before)
            expect_dropped, expect_queued, socks = burst(ctx, endpoint, rng)
            sent += GARBAGE + PEERS + FLOOD + 3
            # The same worker answers at once, and its queue drains.
            asked = time.monotonic()
            assert worker.call("ping", timeout=10)["pid"] == worker.pid
            pings.append(time.monotonic() - asked)
            # Every peer is served in turn: the garbage of the others may still be on its way in.
            target = dropped_before + expect_dropped
            poll_until(lambda t=target: worker.stats()["details"]["ipc_dropped_frames"] >= t, 60,
                       interval=0.1, message=f"{expect_dropped} garbage frames dropped")
            # ... and so is the flood: the queue may run empty between two of its batches.
            target = outcomes_before + expect_queued
            poll_until(lambda t=target: queue_outcomes(worker.stats()) >= t, 60, interval=0.1,
                       message=f"{expect_queued} queued commands run or refused")
            poll_until(lambda: worker.stats()["executor"]["queue_depth"] == 0, 60, message="queue drained")
            assert worker.sample("/hostile_ipc/nobody")["status"] == "metadata_only"
            assert worker.call("type_info", {"type": "std_msgs/msg/String"})["type"] == "std_msgs/msg/String"
            for s in socks:
                s.close()
            # Descriptors come back once the peers are gone.
            poll_until(lambda: proc.num_fds() <= fds_before + 4, 30, interval=0.2,
                       message=f"descriptors back near {fds_before} (now {proc.num_fds()})")
            time.sleep(0.5)
            rss_after_burst.append(rss())
        stats = worker.stats()
        assert stats["executor"]["queue_max_depth_observed"] <= MAX_QUEUE
        assert stats["executor"]["queue_dropped"] > 0, "the flood never met the queue bound"
        assert worker.proc.poll() is None and worker.call("ping")["pid"] == worker.pid
        record("hostile IPC", requests=sent,
               statuses={"dropped": stats["details"]["ipc_dropped_frames"],
                         "backpressure": stats["executor"]["queue_dropped"]},
               worst_ms=max(pings) * 1000, restarts=0,
               rss_before={"rosworker": rss_before}, rss_after={"rosworker": rss_after_burst[-1]},
               note=f"{BURSTS} bursts of {GARBAGE} garbage frames, {PEERS} vanishing peers, {FLOOD} unread "
                    f"commands; RSS after each burst: {', '.join(f'{r:.0f}' for r in rss_after_burst)} MB; "
                    "worst = ping right after a burst")
        # Bounded: a burst raises the allocator's high-water mark (zmq buffers the whole burst) and
        # RSS moves up and down by some MB between bursts; it must not keep climbing.
        assert max(rss_after_burst) - rss_before < scaled(128, 256), (rss_before, rss_after_burst)
        if len(rss_after_burst) >= 6:
            assert max(rss_after_burst[-3:]) - max(rss_after_burst[:3]) < 24, (rss_before, rss_after_burst)
    finally:
        ctx.destroy(linger=0)
        worker.stop()
