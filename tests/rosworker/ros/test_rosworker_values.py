"""Value fidelity through the real ROS worker: real types, not strings."""

from __future__ import annotations

import base64
import uuid

import orjson
import pytest

from tests.support.rospub import publisher
from tests.support.rosworker import RosWorker


@pytest.fixture(scope="module")
def worker():
    w = RosWorker()
    yield w
    w.stop()


def read(worker, type_name: str, value: dict, **sample_args) -> tuple[bytes, dict]:
    topic = f"/t{uuid.uuid4().hex[:8]}/value"
    node = publisher("value", topic, type_name, value)
    try:
        reply = worker.sample_data(topic)
        if sample_args:
            reply = worker.sample(topic, **sample_args)
        return reply["data_json"], reply
    finally:
        node.stop()


def test_string_that_looks_like_a_number_stays_a_string(worker):
    text, _ = read(worker, "std_msgs/msg/String", {"data": "123"})
    assert text == b'{"data":"123"}'


def test_float_one_stays_a_float(worker):
    text, _ = read(worker, "std_msgs/msg/Float64", {"data": 1.0})
    assert text == b'{"data":1.0}'
    assert type(orjson.loads(text)["data"]) is float


def test_empty_arrays_stay_arrays(worker):
    text, _ = read(worker, "sensor_msgs/msg/Image", {"height": 0, "encoding": "rgb8"})
    data = orjson.loads(text)
    assert data["data"] == []
    assert data["encoding"] == "rgb8"


def test_uint8_arrays_are_integer_arrays_or_base64_on_request(worker):
    text, _ = read(worker, "std_msgs/msg/UInt8MultiArray", {"data": [0, 1, 254, 255]})
    assert orjson.loads(text)["data"] == [0, 1, 254, 255]
    text, _ = read(worker, "std_msgs/msg/UInt8MultiArray", {"data": [0, 1, 254, 255]}, bytes="base64")
    assert base64.b64decode(orjson.loads(text)["data"]) == bytes([0, 1, 254, 255])


def test_byte_arrays_are_integer_arrays(worker):
    text, _ = read(worker, "std_msgs/msg/ByteMultiArray", {"data": {"__bytes__": [7, 0, 200]}})
    assert orjson.loads(text)["data"] == [7, 0, 200]


def test_nested_messages_and_time(worker):
    text, reply = read(worker, "geometry_msgs/msg/PoseStamped", {
        "header": {"stamp": {"sec": 1769955040, "nanosec": 286555163}, "frame_id": "map"},
        "pose": {"position": {"x": 1.5, "y": -2.0, "z": 0.0}}})
    data = orjson.loads(text)
    assert data["header"] == {"stamp": {"sec": 1769955040, "nanosec": 286555163}, "frame_id": "map"}
    assert data["pose"]["position"] == {"x": 1.5, "y": -2.0, "z": 0.0}
    assert data["pose"]["orientation"] == {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
    assert reply["type"] == "geometry_msgs/msg/PoseStamped"
    assert isinstance(reply["timestamp"], int) and reply["timestamp"] > 1_600_000_000 * 10**9


def test_a_converted_sample_is_reused_until_a_newer_message_arrives(worker):
    topic = f"/t{uuid.uuid4().hex[:8]}/slow"
    node = publisher("slow", topic, "std_msgs/msg/String", {"data": "s"}, rate=0.5)
    try:
        first = worker.sample_data(topic)
        again = worker.sample(topic)
        assert again["timestamp"] == first["timestamp"]
        assert again["data_json"] == first["data_json"]
    finally:
        node.stop()


def test_nan_and_infinities_are_told_apart(worker):
    """REP 117: NaN (invalid), +inf (no return) and -inf (too close) must not all become null."""
    nan, inf = float("nan"), float("inf")
    text, _ = read(worker, "sensor_msgs/msg/LaserScan",
                   {"ranges": [1.5, nan, inf, -inf], "range_min": 0.25, "range_max": inf,
                    "intensities": [nan, 2.0]})
    data = orjson.loads(text)
    assert data["ranges"] == [1.5, "NaN", "Infinity", "-Infinity"]
    assert data["range_max"] == "Infinity" and data["range_min"] == 0.25
    assert data["intensities"] == ["NaN", 2.0]
