"""rosworker/data/commands.py: what a command's arguments may be, checked at the ROS worker's boundary."""

from __future__ import annotations

import pytest
from rclpy.validate_full_topic_name import validate_full_topic_name

from app.core.errors import ApiError
from ipc.errors import IpcError
from rosworker.data.commands import middleware_names
from tests.support.rosworker import RosWorker


@pytest.fixture(scope="module")
def worker():
    w = RosWorker()
    yield w
    w.stop()


@pytest.mark.parametrize("cmd, args", [
    ("sample", {"timeout_ms": 100}),
    ("subscribe", {}),
    ("evict", {}),
    ("publish", {"type": "std_msgs/msg/Bool", "data": {"data": True}}),
])
def test_names_rmw_refuses_are_invalid_topic_and_no_traceback(worker, cmd, args):
    """Straight to the worker, past the HTTP side's check: rmw's 247-character limit holds here too."""
    before = len(worker.output)
    for length in (248, 250, 255, 256):
        topic = "/" + "t" * (length - 1)
        with pytest.raises(IpcError) as info:
            worker.call(cmd, {"topic": topic, **args})
        assert info.value.code == "invalid-topic", info.value
        assert ApiError.from_ipc(info.value).status == 400 and "247" in info.value.message
    assert worker.call("ping")["pid"] == worker.pid
    logged = "\n".join(worker.output[before:])
    assert "Traceback" not in logged and "ERROR" not in logged, logged


def test_rclpy_name_exceptions_become_invalid_topic():
    """Whatever name rclpy itself refuses (the real validator) is the client's error, not a crash."""
    for name in ("/" + "x" * 300, "/a//b", "/1a"):
        with pytest.raises(IpcError) as info, middleware_names(name):
            validate_full_topic_name(name)
        assert info.value.code == "invalid-topic" and ApiError.from_ipc(info.value).status == 400
        assert info.value.params == {"topic": name[:300]}
        assert info.value.message.startswith("The ROS middleware refuses the topic name")
        assert "\n" not in info.value.message
    with middleware_names("/fine"):  # nothing to map: no error
        validate_full_topic_name("/fine")
    with pytest.raises(ValueError), middleware_names("/x"):  # other errors pass through unchanged
        raise ValueError("not a name problem")
