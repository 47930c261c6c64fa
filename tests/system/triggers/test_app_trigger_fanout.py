"""One payload per message, whatever the number of triggers (issue 33), through a real gateway.

A real publisher whose every message the test chooses, a gateway with two HTTP
workers, and a raw ZeroMQ subscriber on the ROS worker's events socket that
sees every trigger frame crossing to the HTTP workers (``t|g|``):

- the triggers one message fires cross once (once more for those in the other
  bytes mode), counted in ``trigger_frames``, and every stream of every one of
  them gets every event it fired on, byte for byte the SSE frame of that one
  buffer; a one-shot among them fires once, and a stream opened after it fired
  gets that event and ends;
- a stalled stream of a trigger whose frames a reading stream shares holds at
  most its bound, drops its oldest (each counted in ``frames_dropped``) and
  keeps the newest, while the reader loses nothing.
"""

from __future__ import annotations

import base64
import itertools
import json
import os
import time
from datetime import UTC, datetime

import pytest
import requests
import zmq

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from ipc import events, protocol
from tests.support.linepub import LinePublisher
from tests.support.sse import EventStream

ON_CHANGE = {"condition_type": "OnChange"}
_names = itertools.count(1)


@pytest.fixture(scope="module")
def gw(gateway):
    return gateway("--workers", "2", "--log-level", "warning")


def stats(gw: Gateway) -> dict:
    return gw.get("/health").json()["x-medkit-streams"]


def sse_block(stamp_ns: int, payload: bytes) -> bytes:
    """What a client reads for one trigger event (the lines of the SSE event, without the blank line)."""
    when = datetime.fromtimestamp(stamp_ns / 1e9, UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"
    return b'data: {"timestamp":"' + when.encode() + b'","payload":' + payload + b"}"


class Tap:
    """A raw subscriber of the trigger frames of the ROS worker's events socket: ``(key, meta, payload)``."""

    def __init__(self, gw: Gateway):
        self.ctx = zmq.Context()
        self.sock = self.ctx.socket(zmq.SUB)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.SUBSCRIBE, events.TRIGGER_GROUP_PREFIX)
        self.sock.connect(events.endpoint(gw.runtime_dir))
        self.frames: list[tuple[bytes, dict, bytes]] = []
        deadline = time.monotonic() + 10
        while True:  # the confirmation: every frame of the prefix sent from now on reaches the tap
            assert self.sock.poll(max(1, int((deadline - time.monotonic()) * 1000))), "the tap was not confirmed"
            if self.sock.recv_multipart() == [events.TRIGGER_GROUP_PREFIX]:
                break

    def take(self, count: int, timeout: float) -> list[tuple[bytes, dict, bytes]]:
        """The frames so far, once there are ``count`` of them or ``timeout`` passed (confirmations of the
        HTTP workers' subscriptions, one frame each, are passed over)."""
        deadline = time.monotonic() + timeout
        while len(self.frames) < count and (left := deadline - time.monotonic()) > 0:
            if self.sock.poll(max(1, int(left * 1000))):
                frames = self.sock.recv_multipart()
                if len(frames) == 3:
                    self.frames.append((frames[0], protocol.unpack(frames[1]), frames[2]))
        return self.frames

    def close(self) -> None:
        self.sock.close()
        self.ctx.term()


class Topic:
    """A publisher of its own (one node, one topic), the app the gateway shows for it, and its triggers."""

    def __init__(self, gw: Gateway, type_name: str):
        n = next(_names)
        self.gw = gw
        self.app = f"fan_node_{os.getpid()}_{n}"
        self.topic = f"/fan{n}/value"
        self.pub = LinePublisher(self.app, self.topic, type_name)
        self.streams: list[EventStream] = []
        poll_until(lambda: gw.get(f"/apps/{self.app}").status_code == 200, 30, message=f"app {self.app}")

    def create(self, condition: dict, query: str = "", **fields) -> dict:
        r = requests.post(self.gw.api + f"/apps/{self.app}/triggers", timeout=10, json={
            "resource": f"/api/v1/apps/{self.app}/data{self.topic}{query}", "trigger_condition": condition,
            **fields})
        assert r.status_code == 201, r.text
        return r.json()

    def stream(self, trigger: dict, **kw) -> EventStream:
        stream = EventStream(self.gw.port, trigger["event_source"], **kw)
        self.streams.append(stream)
        assert stream.status == 200, stream.body
        return stream

    def close(self) -> None:
        for stream in self.streams:
            stream.close()
        self.pub.stop()


def test_the_triggers_one_message_fires_cross_once_and_each_of_their_streams_gets_each_event_unchanged(gw):
    topic = Topic(gw, "std_msgs/msg/UInt8MultiArray")
    tap = Tap(gw)
    try:
        shared = [topic.create(ON_CHANGE, path="/data", multishot=True) for _ in range(6)]
        in_base64 = topic.create(ON_CHANGE, query="?bytes=base64", path="/data", multishot=True)
        once = topic.create(ON_CHANGE, path="/data")  # a one-shot
        ranged = topic.create({"condition_type": "EnterRange", "lower_bound": 10, "upper_bound": 20},
                              path="/data/0", multishot=True)
        topic.pub.wait_subscribers(1)
        streams = {t["id"]: [topic.stream(t)] for t in (*shared, in_base64, ranged)}
        streams[shared[0]["id"]].append(topic.stream(shared[0]))  # two streams of one trigger
        before = stats(gw)
        values = [1, 2, 15, 3, 4]
        for value in values:
            topic.pub.send({"data": [value, value + 1, value + 2]})

        # The wire: one frame per message for the triggers in bytes mode array, one for the one in base64.
        frames = tap.take(2 * len(values), timeout=15)
        array_key = events.trigger_group_key("data", "array", topic.topic)
        base64_key = events.trigger_group_key("data", "base64", topic.topic)
        assert [key for key, _, _ in frames] == [array_key, base64_key] * len(values), frames
        arrays = [(meta, payload) for key, meta, payload in frames if key == array_key]
        base64s = [(meta, payload) for key, meta, payload in frames if key == base64_key]
        ids = sorted(t["id"] for t in shared)
        assert [sorted(entry[0] for entry in meta["fired"]) for meta, _ in arrays] == [
            sorted([*ids, once["id"]]), ids, sorted([*ids, ranged["id"]]), ids, ids]
        assert [[entry[0] for entry in meta["fired"]] for meta, _ in base64s] == [[in_base64["id"]]] * len(values)
        # Each trigger its own seq (one more each event) and last (the one-shot's only).
        assert all(entry[2] == (entry[0] == once["id"]) for _, meta, _ in frames for entry in meta["fired"])
        seqs = [entry[1] for meta, _ in arrays for entry in meta["fired"] if entry[0] == shared[0]["id"]]
        assert seqs == list(range(seqs[0], seqs[0] + len(values)))
        assert all("error" not in meta for _, meta, _ in frames)
        assert [json.loads(payload)["data"] for _, payload in arrays] == [[v, v + 1, v + 2] for v in values]
        assert [json.loads(payload)["data"] for _, payload in base64s] == [
            base64.b64encode(bytes([v, v + 1, v + 2])).decode() for v in values]
        poll_until(lambda: stats(gw)["trigger_frames"] - before["trigger_frames"] >= 2 * len(values), 10,
                   message="the frames counted")
        after = stats(gw)
        assert after["trigger_frames"] - before["trigger_frames"] == 2 * len(values)
        # Each trigger's own event for each message that fired it: 6 x 5, the base64 one's 5, one each for the
        # one-shot and the range.
        assert after["trigger_events"] - before["trigger_events"] == 6 * 5 + 5 + 1 + 1

        # Each stream: the event of every frame that fired its trigger, as the SSE bytes of that one buffer.
        wanted = {t["id"]: [sse_block(meta["ts"], payload) for meta, payload in arrays] for t in shared}
        wanted[in_base64["id"]] = [sse_block(meta["ts"], payload) for meta, payload in base64s]
        wanted[ranged["id"]] = [sse_block(arrays[2][0]["ts"], arrays[2][1])]
        for trigger_id, opened in streams.items():
            for stream in opened:
                got = stream.take(len(wanted[trigger_id]), timeout=10)
                assert len(got) == len(wanted[trigger_id]), (trigger_id, got)
                assert stream.blocks == wanted[trigger_id], trigger_id
        # The one-shot fired once, before any stream of it opened: a stream opened now gets it, then ends.
        late = topic.stream(once)
        assert late.next(timeout=10) is not None and late.blocks == [sse_block(arrays[0][0]["ts"], arrays[0][1])]
        assert late.ended(10)
        # Nothing more crossed, nothing more came.
        assert len(tap.take(2 * len(values) + 1, timeout=0.5)) == 2 * len(values)
        assert all(stream.collect(0.1) == [] for opened in streams.values() for stream in opened)
    finally:
        tap.close()
        topic.close()


def test_a_stalled_stream_drops_its_oldest_and_counts_them_while_a_reader_of_the_same_frames_loses_nothing(gw):
    topic = Topic(gw, "std_msgs/msg/String")
    try:
        triggers = [topic.create(ON_CHANGE, multishot=True) for _ in range(5)]
        topic.pub.wait_subscribers(1)
        reader = topic.stream(triggers[0])
        stalled = topic.stream(triggers[1], recv_buffer=4096)  # not read until the end
        before = stats(gw)
        count, filler = 150, "x" * 20000  # 150 events of 20 kB: far past a stream's 1 MiB and its socket's buffers
        for n in range(count):
            topic.pub.send({"data": f"{n:04d}{filler}"})
            assert reader.next(timeout=10)["payload"] == {"data": f"{n:04d}{filler}"}  # the reader keeps up
        poll_until(lambda: stats(gw)["trigger_frames"] - before["trigger_frames"] >= count, 10,
                   message="the frames counted")
        after = stats(gw)
        assert after["trigger_frames"] - before["trigger_frames"] == count  # one a message, for five triggers
        assert after["trigger_events"] - before["trigger_events"] == 5 * count
        # The stalled client now reads: what its stream kept, in order, ending with the newest.
        got = []
        while not got or got[-1] != f"{count - 1:04d}":
            event = stalled.next(timeout=10)
            assert event is not None, got
            got.append(event["payload"]["data"][:4])
        assert got == sorted(got) and len(set(got)) == len(got)
        # At most the stream's bound (1 MiB: 52 of these events) and what the kernel's buffers held: the rest
        # was dropped, oldest first, each drop counted.
        assert len(got) <= 52 + 25, len(got)
        # (/health reads the HTTP workers' sums each at most STREAM_TOTALS_TTL old: polled until they show it.)
        poll_until(lambda: stats(gw)["frames_dropped"] - before["frames_dropped"] >= count - len(got), 10,
                   message="the stalled stream's drops counted")
        assert stalled.collect(0.3) == [] and reader.collect(0.1) == []  # past the sums' TTL: any worker's is current
        assert stats(gw)["frames_dropped"] - before["frames_dropped"] == count - len(got)
    finally:
        topic.close()
