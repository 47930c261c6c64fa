"""rosworker/data/ticks.py: tick phase per topic (issue 23).

A topic's ticks follow its messages' arrivals (the received stamp a take gives),
and the cadence does not change: one frame per interval with the latest value,
whether or not it changed, and the ticks keep the interval when messages stop.

In-process, as tests/rosworker/subscriptions/test_rosworker_streams.py: a real ROS thread and
events socket; the pool is a stand-in whose messages' received stamps the test
sets.  Through a real gateway and publisher: tests/reliability/test_stream_phase.py (make reliability).
"""

from __future__ import annotations

import statistics
import time

import pytest

from ipc import events
from rosworker.data import ticks as streams_module
from tests.rosworker.subscriptions.test_rosworker_streams import TOPIC, TYPE, FakePool, Setup
from tests.support.rosunit import RosThread

OTHER = "/engine/pressure"
FAST_MS = events.INTERVALS["fast"] * 1000


class ArrivalPool(FakePool):
    """FakePool whose data answers carry ``received[topic]`` (wall-clock ns) as their timestamp."""

    def __init__(self):
        super().__init__()
        self.received: dict[str, int] = {}

    def peek(self, topic: str, mode: str):
        result = super().peek(topic, mode)
        if result is not None and result.get("status") == "data" and topic in self.received:
            result = {**result, "timestamp": self.received[topic]}
        return result


@pytest.fixture
def phased(tmp_path):
    with RosThread(tmp_path) as ros:
        setup = Setup(ros)
        setup.pool = setup.ticks.pool = ArrivalPool()
        setup.pool.entries = {}
        yield setup
        setup.close()


def arrive(s, topic: str, payload: bytes, phase_ms: float) -> int:
    """A message of ``topic`` received at the last wall time whose offset in the fast grid is ``phase_ms``."""
    now = time.time_ns()
    period = int(FAST_MS * 1e6)
    received = now - (now % period) + int(phase_ms * 1e6)
    if received > now:
        received -= period
    s.pool.messages[topic] = payload
    s.pool.received[topic] = received
    return received


def frames(s, interval: str, topic: str, count: int) -> list[tuple[dict, bytes]]:
    return [s.frame(interval, topic) for _ in range(count)]


def offset_ms(meta: dict, received: int, period_ms: float) -> float:
    """Where a frame's tick fell after the message's arrival, within one period."""
    return ((meta["ts"] - received) / 1e6) % period_ms


def test_each_topics_ticks_follow_its_own_arrivals(phased):
    s = phased
    s.node.add("/engine/temp_sensor", pub=[(TOPIC, TYPE), (OTHER, TYPE)])  # one node publishes both
    s.ros.call(s.graph.tick)
    a = arrive(s, TOPIC, b'{"data":"a"}', 5.0)
    b = arrive(s, OTHER, b'{"data":"b"}', 30.0)
    s.create(topic=TOPIC)
    s.create(topic=OTHER)
    # The first frame of each comes on the grid and sets the phase; the rest follow the arrivals.
    frames(s, "fast", TOPIC, 3)
    frames(s, "fast", OTHER, 3)
    got_a, got_b = frames(s, "fast", TOPIC, 8), frames(s, "fast", OTHER, 8)
    assert {d for _, d in got_a} == {b'{"data":"a"}'} and {d for _, d in got_b} == {b'{"data":"b"}'}
    on_a = [offset_ms(m, a, FAST_MS) for m, _ in got_a]
    on_b = [offset_ms(m, b, FAST_MS) for m, _ in got_b]
    margin = streams_module.PHASE_MARGIN * 1000
    # A tick is never before margin after its arrival, and (a loaded machine's timer lateness aside)
    # close to it: the median is what an unphased grid would put anywhere in [0, 50) ms.
    assert all(x >= margin - 0.5 for x in on_a + on_b), (on_a, on_b)
    assert statistics.median(on_a) < margin + 10 and statistics.median(on_b) < margin + 10, (on_a, on_b)
    assert s.ros.call(lambda: s.stats.phase_changes) == 2          # once per topic: its first message


def test_cadence_and_payloads_are_those_of_the_grid(phased):
    s = phased
    s.publisher_appears()
    arrive(s, TOPIC, b'{"data":1}', 17.0)
    s.create(topic=TOPIC, interval="fast")
    s.create(topic=TOPIC, interval="normal")
    got = frames(s, "fast", TOPIC, 12)
    stamps = [m["ts"] for m, _ in got]
    # one frame per interval: no two ticks of the same topic within half an interval (the phase change
    # included), and no tick skipped: the span is the count's worth of intervals
    gaps = [(b - a) / 1e6 for a, b in zip(stamps, stamps[1:], strict=False)]
    assert min(gaps) >= FAST_MS / 2 - 5, gaps
    assert len(got) - 1 <= round((stamps[-1] - stamps[0]) / 1e6 / FAST_MS) + 1, gaps
    # the latest value every tick, changed or not (no new message since the first)
    assert {d for _, d in got} == {b'{"data":1}'} and all(m["status"] == "data" for m, _ in got)
    arrive(s, TOPIC, b'{"data":2}', 40.0)
    assert s.frame("fast", TOPIC)[1] in (b'{"data":1}', b'{"data":2}')
    assert {d for _, d in frames(s, "fast", TOPIC, 3)} == {b'{"data":2}'}
    normal = frames(s, "normal", TOPIC, 3)
    assert {d for _, d in normal} == {b'{"data":2}'}
    normal_gaps = [(b["ts"] - a["ts"]) / 1e6 for (a, _), (b, _) in zip(normal, normal[1:], strict=False)]
    assert min(normal_gaps) >= events.INTERVALS["normal"] * 500 - 5, normal_gaps


def test_ticks_keep_the_interval_and_phase_when_messages_stop(phased):
    s = phased
    s.publisher_appears()
    received = arrive(s, TOPIC, b'{"data":"last"}', 12.0)
    s.create(topic=TOPIC)
    frames(s, "fast", TOPIC, 3)              # phased now; no message comes after this one
    later = frames(s, "fast", TOPIC, 10)
    assert {d for _, d in later} == {b'{"data":"last"}'}
    offsets = [offset_ms(m, received, FAST_MS) for m, _ in later]
    assert statistics.median(offsets) < streams_module.PHASE_MARGIN * 1000 + 10, offsets
    stamps = [m["ts"] for m, _ in later]
    assert round((stamps[-1] - stamps[0]) / 1e6 / FAST_MS) == len(later) - 1   # one a period, none skipped
    assert s.ros.call(lambda: s.stats.phase_changes) == 1


def test_a_topic_that_drifts_out_of_phase_is_phased_again(phased, monkeypatch):
    monkeypatch.setattr(streams_module, "PHASE_HOLD", 0.2)
    s = phased
    s.publisher_appears()
    arrive(s, TOPIC, b'{"n":0}', 5.0)
    s.create(topic=TOPIC)
    frames(s, "fast", TOPIC, 3)
    # Its messages now arrive 25 ms after the ticks: each new one is taken ~23 ms late.
    received = 0
    for n in range(1, streams_module.PHASE_MISSES + 3):
        received = arrive(s, TOPIC, b'{"n":%d}' % n, 30.0)
        while s.frame("fast", TOPIC)[1] != b'{"n":%d}' % n:
            pass
    assert s.ros.call(lambda: s.stats.phase_changes) == 2
    later = [offset_ms(m, received, FAST_MS) for m, _ in frames(s, "fast", TOPIC, 8)]
    assert statistics.median(later) < streams_module.PHASE_MARGIN * 1000 + 10, later


def test_a_watch_that_leaves_ends_its_phase_timer(phased):
    s = phased
    s.publisher_appears()
    arrive(s, TOPIC, b"{}", 20.0)
    sub = s.create(topic=TOPIC)
    frames(s, "fast", TOPIC, 3)
    assert s.ros.call(lambda: [k for k, g in s.ticks._groups.items() if k[1] is not None and g])
    s.ros.call(s.registry.delete, "apps", "temp_sensor", sub["id"])
    time.sleep(0.2)   # past the phase group's next tick (the timer ends there; nothing to wait on)
    assert s.ros.call(lambda: [k for k in s.ticks._groups if k[1] is not None]) == []
    assert s.ros.call(lambda: dict(s.ticks._phases)) == {}
