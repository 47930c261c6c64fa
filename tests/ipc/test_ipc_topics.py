"""ipc/topics.py: the gateway's topic-name rules are rmw's own (checked against rclpy's validator)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rclpy.exceptions import InvalidTopicNameException
from rclpy.validate_full_topic_name import validate_full_topic_name

from ipc.topics import MAX_TOPIC_LENGTH, InvalidTopic, normalize_topic


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
