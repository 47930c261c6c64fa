"""ROS topic names: one validation for the HTTP side and the ROS worker.

A fully qualified ROS 2 topic name is ``/`` followed by tokens separated by
``/``; a token is letters, digits and ``_`` and does not start with a digit;
no empty tokens, no trailing ``/``.  The ROS middleware caps names near 255
characters; we refuse longer ones before they reach it.
"""

from __future__ import annotations

import re

MAX_TOPIC_LENGTH = 255
_TOPIC = re.compile(r"(?:/[A-Za-z_][A-Za-z0-9_]*)+")


class InvalidTopic(ValueError):
    """The name cannot be a ROS topic; ``str(exc)`` says why, for a person."""


def normalize_topic(name: object) -> str:
    """Return the fully qualified form of ``name`` (a missing leading ``/`` is added)."""
    if not isinstance(name, str):
        raise InvalidTopic("topic must be a string")
    if not name:
        raise InvalidTopic("topic is empty")
    if len(name) > MAX_TOPIC_LENGTH + 1:
        raise InvalidTopic(f"topic is longer than {MAX_TOPIC_LENGTH} characters")
    topic = name if name.startswith("/") else "/" + name
    if len(topic) > MAX_TOPIC_LENGTH:
        raise InvalidTopic(f"topic is longer than {MAX_TOPIC_LENGTH} characters")
    if not _TOPIC.fullmatch(topic):
        raise InvalidTopic(
            f"{name!r} is not a valid ROS topic name: use /-separated tokens of letters, digits "
            "and _, each not starting with a digit (e.g. /powertrain/engine/temperature)"
        )
    return topic
