"""ROS topic names: one validation for the HTTP side and the ROS worker.

The rules are rmw's for a fully qualified topic name
(``rmw_validate_full_topic_name``, what rclpy's ``validate_full_topic_name``
and every ``create_subscription``/``create_publisher``/graph query apply):
``/`` followed by tokens separated by ``/``; a token is ASCII letters, digits
and ``_`` and does not start with a digit; no empty tokens, no trailing
``/``; at most ``RMW_TOPIC_MAX_NAME_LENGTH`` = 255 - 8 = 247 characters
(room for the DDS prefix ``rt/`` and its kin).  A name that breaks them is
refused here, before it reaches the middleware (whose exception would
otherwise be a 500).  tests/ipc/test_ipc_topics.py checks the two agree.
"""

from __future__ import annotations

import re

MAX_TOPIC_LENGTH = 247  # rmw's RMW_TOPIC_MAX_NAME_LENGTH, the leading "/" included
_TOPIC = re.compile(r"(?:/[A-Za-z_][A-Za-z0-9_]*)+")


class InvalidTopic(ValueError):
    """The name cannot be a ROS topic; ``str(exc)`` says why, for a person."""


def normalize_topic(name: object) -> str:
    """Return the fully qualified form of ``name`` (a missing leading ``/`` is added)."""
    if not isinstance(name, str):
        raise InvalidTopic("topic must be a string")
    if not name:
        raise InvalidTopic("topic is empty")
    topic = name if name.startswith("/") else "/" + name
    if len(topic) > MAX_TOPIC_LENGTH:
        raise InvalidTopic(f"topic is longer than {MAX_TOPIC_LENGTH} characters "
                           "(the ROS middleware's limit, the leading / included)")
    if not _TOPIC.fullmatch(topic):
        raise InvalidTopic(
            f"{name!r} is not a valid ROS topic name: use /-separated tokens of letters, digits "
            "and _, each not starting with a digit (e.g. /powertrain/engine/temperature)"
        )
    return topic
