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

Message type names (``pkg/msg/Name``, what a PUT body's ``type`` and the ROS worker's
``type_info``/``publish`` take) follow rosidl's rules (``rosidl_adapter.parser``): a package
name is lower-case (``[a-z][a-z0-9_]*``, REP 144) and a message name is CamelCase
(``[A-Z][A-Za-z0-9]*``, no ``_``).  The HTTP side checks the format with :data:`MESSAGE_TYPE`
before anything is sent; the ROS worker checks it again before it imports a package.
"""

from __future__ import annotations

import re

MAX_TOPIC_LENGTH = 247  # rmw's RMW_TOPIC_MAX_NAME_LENGTH, the leading "/" included
_TOPIC = re.compile(r"(?:/[A-Za-z_][A-Za-z0-9_]*)+")
#: Exactly ``pkg/msg/Name`` (use with ``fullmatch``); the groups are the package and the name.
MESSAGE_TYPE = re.compile(r"([a-z][a-z0-9_]*)/msg/([A-Z][A-Za-z0-9]*)")
MAX_TYPE_LENGTH = 256


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


def valid_message_type(name: object) -> bool:
    """True for a string of at most ``MAX_TYPE_LENGTH`` characters that is exactly ``pkg/msg/Name``."""
    return isinstance(name, str) and len(name) <= MAX_TYPE_LENGTH and MESSAGE_TYPE.fullmatch(name) is not None
