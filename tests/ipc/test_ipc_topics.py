"""ipc/topics.py: the gateway's topic-name rules are rmw's own (checked against rclpy's validator)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rclpy.exceptions import InvalidTopicNameException
from rclpy.validate_full_topic_name import validate_full_topic_name
from rosidl_adapter.parser import is_valid_message_name, is_valid_package_name

from ipc.topics import (
    MAX_TOPIC_LENGTH,
    MESSAGE_TYPE,
    InvalidTopic,
    normalize_topic,
    valid_message_type,
)


def rclpy_accepts(full_name: str) -> bool:
    try:
        return bool(validate_full_topic_name(full_name))
    except InvalidTopicNameException:
        return False


def we_accept(name: str) -> bool:
    try:
        normalize_topic(name)
        return True
    except InvalidTopic:
        return False


def test_the_length_limit_is_the_middlewares():
    assert MAX_TOPIC_LENGTH == 247
    longest = "/" + "a" * (MAX_TOPIC_LENGTH - 1)
    assert rclpy_accepts(longest) and not rclpy_accepts(longest + "a")
    assert normalize_topic(longest) == longest
    assert normalize_topic(longest[1:]) == longest  # the leading "/" is added, and counted
    for length in range(MAX_TOPIC_LENGTH + 1, 256):
        for name in ("/" + "a" * (length - 1), "a" * (length - 1), "/ab/" + "c" * (length - 4)):
            with pytest.raises(InvalidTopic, match="longer than 247 characters"):
                normalize_topic(name)


@pytest.mark.parametrize("name", [
    "/a", "/a/b_c/D9", "/_hidden/x", "/a" * 120, "/" + "x" * 246, "/a/" + "b" * 244,
    "/", "", "//a", "/a//b", "/a/", "/1a", "/a/9", "/a b", "/a-b", "/a.b", "/~/a", "/{ns}/a",
    "/é", "/a\nb", "/" + "x" * 247, "/a/" + "b" * 245,
])
def test_known_names_agree_with_rclpy(name):
    assert we_accept(name) == rclpy_accepts(name), name


# Names of the alphabet that matters to rmw, at every length around the limit.
_CHARS = st.sampled_from("aZ_09/~{}-. é")
_NAMES = st.one_of(
    st.text(_CHARS, max_size=20),
    st.builds(lambda body, n: "/" + (body * 300)[:n], st.text(_CHARS, min_size=1, max_size=6),
              st.integers(min_value=MAX_TOPIC_LENGTH - 4, max_value=MAX_TOPIC_LENGTH + 4)),
)


@settings(max_examples=600, deadline=None, derandomize=True, database=None)
@given(_NAMES)
def test_random_names_agree_with_rclpy(name):
    full = name if name.startswith("/") else "/" + name
    assert we_accept(full) == rclpy_accepts(full), full


# Message type names: the one check (HTTP side and ROS worker) against rosidl's own rules.
TYPE_NAMES = ["std_msgs/msg/String", "a/msg/B", "my_pkg2/msg/Foo2Bar", "sensor_msgs/msg/Image",
              "Std_msgs/msg/String", "STD_MSGS/msg/String", "std_msgs/msg/string", "std_msgs/msg/Str_ing",
              "std-msgs/msg/X", "_hidden/msg/X", "1pkg/msg/X", "std_msgs/srv/Empty", "std_msgs/String",
              "std_msgs/msg/", "/msg/String", "std_msgs/msg/String/", "a/b/msg/C", "std_msgs/msg/Bo-ol"]


@pytest.mark.parametrize("name", TYPE_NAMES)
def test_message_types_follow_rosidls_rules(name):
    pkg, sep, rest = name.partition("/msg/")
    rosidl = bool(sep) and is_valid_package_name(pkg) and is_valid_message_name(rest)
    # rosidl also refuses "__" and a trailing "_" in a package name; no installed package has them,
    # and the ROS worker answers such a name "type-not-installed".
    assert valid_message_type(name) is rosidl, name
    assert (MESSAGE_TYPE.fullmatch(name) is not None) is rosidl, name


def test_message_type_length_and_kind():
    assert valid_message_type("a/msg/" + "B" * (256 - 6))
    assert not valid_message_type("a/msg/" + "B" * (256 - 5))
    for not_a_string in (None, 5, b"std_msgs/msg/String", ["std_msgs/msg/String"]):
        assert not valid_message_type(not_a_string)
