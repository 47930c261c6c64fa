"""The data family's commands (``sample``, ``subscribe``, ``evict``, ``pool``, ``publish``, ``type_info``).

Each handler validates its ``args`` (``core/args.py``: nothing a client sends
may raise anything but :class:`IpcError`), then answers with ``task.reply`` now
or later (a cold sample).  The message shapes are in ``ipc/PROTOCOL.md``.

A topic is checked with ``ipc.topics`` (rmw's rules) first; should rclpy
still refuse a name, the handlers that hand a topic to rclpy run inside
:func:`middleware_names`, which makes that the client's ``invalid-topic``
instead of an internal error with a traceback.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable, Iterator
from typing import Any

from rclpy.exceptions import NameValidationException

from ipc.errors import IpcError

from ..core import args
from ..core.task import Task
from ..ros import msgtypes
from ..ros.schema import default_value, schema
from .pool import TopicPool
from .publishers import PublisherPool


@contextlib.contextmanager
def middleware_names(topic: str) -> Iterator[None]:
    """rclpy's name exceptions (``InvalidTopicNameException`` and kin) -> IpcError("invalid-topic")."""
    try:
        yield
    except NameValidationException as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise IpcError("invalid-topic", f"The ROS middleware refuses the topic name: {reason[:200]}",
                       {"topic": str(topic)[:300]}) from None


def _topic_handler(handler: Callable[[Commands, Task], None]) -> Callable[[Commands, Task], None]:
    """A handler that hands ``args["topic"]`` to rclpy: its name errors are the client's."""
    @functools.wraps(handler)
    def run(self: Commands, task: Task) -> None:
        with middleware_names(task.args.get("topic")):
            handler(self, task)
    return run


class Commands:
    """The data family's handlers; ``handlers`` (name -> handler) goes to the executor."""

    def __init__(self, pool: TopicPool, publishers: PublisherPool, *, sample_timeout: float):
        self.pool = pool
        self.publishers = publishers
        self.sample_timeout = sample_timeout
        self.handlers: dict[str, Callable[[Task], None]] = {
            "sample": self.sample, "subscribe": self.subscribe, "evict": self.evict,
            "publish": self.publish, "type_info": self.type_info, "pool": self.pool_cmd,
        }

    @_topic_handler
    def sample(self, task: Task) -> None:
        topic = args.topic(task.args)
        timeout = args.number(task.args, "timeout_ms", self.sample_timeout * 1000, 0, 30000) / 1000
        self.pool.sample(task, topic, timeout, args.bytes_mode(task.args, default="array"))

    @_topic_handler
    def subscribe(self, task: Task) -> None:
        task.reply(self.pool.subscribe(args.topic(task.args)))

    @_topic_handler
    def evict(self, task: Task) -> None:
        topic = args.topic(task.args)
        task.reply({"topic": topic, "evicted": self.pool.evict_topic(topic)})

    def pool_cmd(self, task: Task) -> None:
        task.reply({"topics": list(self.pool.entries)})

    @_topic_handler
    def publish(self, task: Task) -> None:
        topic = args.topic(task.args)
        type_name = task.args.get("type")
        data = task.args.get("data")
        if not isinstance(type_name, str):
            raise IpcError("bad-request", "type: missing required field")
        if not isinstance(data, dict):
            raise IpcError("bad-request", "data: must be an object")
        self.publishers.publish(task, topic, type_name, data)

    def type_info(self, task: Task) -> None:
        type_name = task.args.get("type")
        if not isinstance(type_name, str):
            raise IpcError("bad-request", "type: missing required field")
        try:
            cls = msgtypes.load_type(type_name)
            info: dict[str, Any] = {"type": type_name, "schema": schema(cls),
                                    "default_value": default_value(cls)}
        except msgtypes.ConversionError as exc:
            raise IpcError(exc.code, exc.message, {"type": type_name[:300]}) from None
        task.reply(info)
