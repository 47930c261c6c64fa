"""The recordings' store and message definitions (rosworker/bulk_data/), on real files.

Recordings are written by the real writer (``RecordingStore.write``: real MCAP files in a temporary
directory) from real CDR (rclpy's ``serialize_message``); only the gateway around it is left out
(the whole path, from publishers to a download: tests/system/bulk_data/test_bulk_data.py).
"""

from __future__ import annotations

import os
import time

import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import UInt8MultiArray

from rosworker.bulk_data import msgdefs
from rosworker.bulk_data.recorder import ENTRY_OVERHEAD, Recording, Ring
from rosworker.bulk_data.writer import RecordingStore, read_meta

CHANNEL = ("/blob", "std_msgs/msg/UInt8MultiArray")


class Counters(dict):
    def __getattr__(self, name):
        return self.get(name, 0)

    def __setattr__(self, name, value):
        self[name] = value


def recording(code: str, kib: int, *, codes=(), at: int | None = None, messages: int = 4) -> Recording:
    """A recording of ``messages`` messages of ``kib`` KiB of random bytes (incompressible) each."""
    now = at or time.time_ns()
    blobs = [serialize_message(UInt8MultiArray(data=os.urandom(kib * 1024))) for _ in range(messages)]
    items = [(now - (messages - i) * 1000, now - (messages - i) * 1000 - 7, CHANNEL, b) for i, b in enumerate(blobs)]
    rec = Recording(f"fault_{code}_{now // 1_000_000}", code, ["/node"], now, items, 1 << 30)
    for extra in codes:
        rec.codes.append(extra)
        rec.sources[extra] = ["/node"]
    rec.ended_ns = now + 1000
    return rec


def store(path, **kw) -> RecordingStore:
    kw.setdefault("max_total_bytes", 1 << 30)
    kw.setdefault("max_per_fault", 1)
    return RecordingStore(str(path), Counters(), **kw)


def test_a_written_recording_reads_back_and_the_index_is_rebuilt_from_the_directory(tmp_path):
    first = store(tmp_path)
    first.load()
    rec = recording("HOT", 2)
    meta = first.write(rec)
    assert meta is not None and os.stat(meta["path"]).st_mode & 0o777 == 0o600
    with open(meta["path"], "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        decoded = [(m.log_time, m.publish_time, bytes(d.data)) for _, _, m, d in reader.iter_decoded_messages()]
    assert [(t, p) for t, p, _ in decoded] == [(i[0], i[1]) for i in rec.items]
    # decoded from the file's own schema: every byte that was published
    assert [d for _, _, d in decoded] == [bytes(deserialize_message(i[3], UInt8MultiArray).data) for i in rec.items]
    # a half-written file of a killed writer, and a file that is no recording of ours
    (tmp_path / ".fault_X_1.mcap.tmp").write_bytes(b"\x89MCAP0\r\n half")
    (tmp_path / "fault_Y_1.mcap").write_bytes(b"not an mcap file")
    again = store(tmp_path)
    again.load()
    assert [r["id"] for r in again.listing()] == [meta["id"]]
    assert again.get(meta["id"])["fault_codes"] == ["HOT"] and again.get(meta["id"])["size"] == meta["size"]
    assert not (tmp_path / ".fault_X_1.mcap.tmp").exists()
    assert read_meta(str(tmp_path / "fault_Y_1.mcap")) is None


def test_the_disk_cap_deletes_the_oldest_recordings_first(tmp_path):
    s = store(tmp_path, max_total_bytes=300 * 1024, max_per_fault=0)
    s.load()
    base = time.time_ns()
    metas = [s.write(recording(f"F{i}", 25, at=base + i * 10**9)) for i in range(4)]  # ~100 KiB each
    kept = [r["id"] for r in s.listing()]
    assert kept == [m["id"] for m in metas[-2:]] or kept == [m["id"] for m in metas[-3:]], kept
    total = sum(r["size"] for r in s.listing())
    assert total <= 300 * 1024 and s.stats.rosbag_disk_bytes == total
    assert s.stats.rosbag_evicted == 4 - len(kept)
    assert sorted(os.listdir(tmp_path)) == sorted(k + ".mcap" for k in kept)


def test_a_fault_keeps_its_newest_recordings_and_a_shared_one_stays_while_a_fault_keeps_it(tmp_path):
    s = store(tmp_path, max_per_fault=1)
    s.load()
    base = time.time_ns()
    burst = s.write(recording("A", 1, codes=("B",), at=base))
    assert s.get(burst["id"])["fault_codes"] == ["A", "B"]
    newer_a = s.write(recording("A", 1, at=base + 10**9))
    assert s.get(burst["id"])["fault_codes"] == ["B"] and s.get(newer_a["id"])["fault_codes"] == ["A"]
    assert [r["id"] for r in s.of_fault("A")] == [newer_a["id"]]
    newer_b = s.write(recording("B", 1, at=base + 2 * 10**9))
    assert s.get(burst["id"]) is None and not os.path.exists(burst["path"])  # kept by no fault any more
    assert [r["id"] for r in s.of_fault("B")] == [newer_b["id"]]
    # the same rule after a restart: the index is rebuilt, the caps applied again
    again = store(tmp_path, max_per_fault=1)
    again.load()
    assert {r["id"]: r["fault_codes"] for r in again.listing()} == {newer_a["id"]: ["A"], newer_b["id"]: ["B"]}


def test_an_unwritable_directory_is_a_counted_error_and_leaves_nothing(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    s = store(blocker / "rosbags")
    s.load()
    assert s.write(recording("HOT", 1)) is None
    assert s.stats.rosbag_write_errors >= 1 and s.listing() == []


def test_the_ring_keeps_its_window_and_its_byte_cap_oldest_first():
    stats = Counters()
    ring = Ring(window_ns=1_000, cap_bytes=3 * (10 + ENTRY_OVERHEAD), stats=stats)
    for t in range(0, 500, 100):
        ring.add((t, t, CHANNEL, b"x" * 10))
    assert [i[0] for i in ring.items] == [200, 300, 400] and stats.rosbag_buffer_drops == 2
    ring.add((2_000, 2_000, CHANNEL, b"x" * 10))  # the others are older than the window: gone, not drops
    assert [i[0] for i in ring.items] == [2_000] and stats.rosbag_buffer_drops == 2
    assert stats.rosbag_buffer_bytes == 10 + ENTRY_OVERHEAD and stats.rosbag_buffer_messages == 1
    assert ring.take() == [(2_000, 2_000, CHANNEL, b"x" * 10)] and stats.rosbag_buffer_bytes == 0


@pytest.mark.parametrize("type_name, nested", [
    ("sensor_msgs/msg/Temperature", ["std_msgs/Header", "builtin_interfaces/Time"]),
    ("nav_msgs/msg/Odometry", ["std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/PoseWithCovariance",
                               "geometry_msgs/Pose",
                               "geometry_msgs/Point", "geometry_msgs/Quaternion", "geometry_msgs/TwistWithCovariance",
                               "geometry_msgs/Twist", "geometry_msgs/Vector3"]),
    ("std_msgs/msg/Float64", []),
])
def test_a_definition_carries_every_nested_type_once_as_rosbag2_writes_it(type_name, nested):
    encoding, text = msgdefs.definition(type_name)
    assert encoding == "ros2msg"
    sections = text.split("\n" + "=" * 80 + "\n")
    assert sections[0] == msgdefs._read(type_name, ".msg")  # the type's own .msg first, as installed
    assert [s.split("\n", 1)[0] for s in sections[1:]] == [f"MSG: {n}" for n in nested]
    assert len(set(sections)) == len(sections)
