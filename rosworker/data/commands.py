"""The queued commands of the IPC protocol, run on the ROS thread.

Each handler validates its ``args`` (nothing a client sends may raise
anything but :class:`IpcError`), then answers with ``task.reply`` now or
later (a cold sample).  The message shapes are in ``ipc/PROTOCOL.md``.

A topic is checked with ``ipc.topics`` (rmw's rules) first; should rclpy
still refuse a name, the handlers that hand a topic to rclpy run inside
:func:`middleware_names`, which makes that the client's ``invalid-topic``
instead of an internal error with a traceback.
"""

from __future__ import annotations

import contextlib
import functools
import time
from collections.abc import Callable, Iterator
from typing import Any

from rclpy.exceptions import NameValidationException

from ipc import events
from ipc.errors import IpcError
from ipc.protocol import BYTES_MODES
from ipc.topics import InvalidTopic, normalize_topic

from ..core.executor import Task
from ..core.graph import GraphMonitor
from ..ros import msgtypes
from ..ros.schema import default_value, schema
from ..subscriptions.registry import StreamRegistry
from .pool import TopicPool
from .publishers import PublisherPool


def _topic(args: dict) -> str:
    try:
        return normalize_topic(args.get("topic"))
    except InvalidTopic as exc:
        raise IpcError("invalid-topic", str(exc), {"topic": str(args.get("topic"))[:300]}) from None


def _string(args: dict, name: str, choices: tuple[str, ...] | None = None, limit: int = 4096) -> str:
    value = args.get(name)
    if not isinstance(value, str) or not value or len(value) > limit or (choices and value not in choices):
        raise IpcError("bad-request", f"{name}: expected " + (f"one of {', '.join(choices)}" if choices
                                                               else f"a string of 1 to {limit} characters"))
    return value


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


def _number(args: dict, name: str, default: float, low: float, high: float) -> float:
    value = args.get(name, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (low <= value <= high):
        raise IpcError("bad-request", f"{name}: expected a number from {low:g} to {high:g}")
    return float(value)


class Commands:
    """The handlers of the queued commands; ``handlers`` (name -> handler) goes to the executor (main.py)."""

    def __init__(self, pool: TopicPool, graph: GraphMonitor, publishers: PublisherPool,
                 streams: StreamRegistry, *, sample_timeout: float, debug: bool):
        self.pool = pool
        self.graph = graph
        self.publishers = publishers
        self.streams = streams
        self.sample_timeout = sample_timeout
        self.handlers: dict[str, Callable[[Task], None]] = {
            "sample": self.sample, "subscribe": self.subscribe, "evict": self.evict,
            "graph": self.graph_cmd, "publish": self.publish, "type_info": self.type_info,
            "pool": self.pool_cmd, "sub_create": self.sub_create, "sub_list": self.sub_list,
            "sub_get": self.sub_get, "sub_update": self.sub_update, "sub_delete": self.sub_delete,
        }
        if debug:
            self.handlers["debug_sleep"] = self.debug_sleep

    @_topic_handler
    def sample(self, task: Task) -> None:
        topic = _topic(task.args)
        timeout = _number(task.args, "timeout_ms", self.sample_timeout * 1000, 0, 30000) / 1000
        mode = task.args.get("bytes", "array")
        if mode not in BYTES_MODES:
            raise IpcError("bad-request", "bytes: expected 'array' or 'base64'")
        self.pool.sample(task, topic, timeout, mode)

    @_topic_handler
    def subscribe(self, task: Task) -> None:
        task.reply(self.pool.subscribe(_topic(task.args)))

    @_topic_handler
    def evict(self, task: Task) -> None:
        topic = _topic(task.args)
        task.reply({"topic": topic, "evicted": self.pool.evict_topic(topic)})

    def pool_cmd(self, task: Task) -> None:
        task.reply({"topics": list(self.pool.entries)})

    def graph_cmd(self, task: Task) -> None:
        since = task.args.get("since")
        if since is not None and (isinstance(since, bool) or not isinstance(since, int)):
            raise IpcError("bad-request", "since: expected an integer generation")
        task.reply(self.graph.snapshot(since))

    @_topic_handler
    def publish(self, task: Task) -> None:
        topic = _topic(task.args)
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

    # ---- cyclic subscriptions (the HTTP side has checked what a client sent; these guard the wire) ----
    def _entity(self, args: dict) -> tuple[str, str]:
        return _string(args, "collection", ("apps", "components", "functions")), _string(args, "entity_id",
                                                                                         limit=256)

    def _duration(self, args: dict) -> int:
        value = args.get("duration")
        limit = self.streams.max_duration
        if isinstance(value, bool) or not isinstance(value, int) or not 0 < value <= limit:
            raise IpcError("bad-request", f"duration: expected an integer from 1 to {limit}")
        return value

    def sub_create(self, task: Task) -> None:
        collection, entity_id = self._entity(task.args)
        mode = _string(task.args, "bytes", BYTES_MODES)
        # The client's address (the per-client cap); absent from an older HTTP side or a probe.
        client = _string(task.args, "client", limit=256) if task.args.get("client") is not None else ""
        kind = task.args.get("kind", "data")  # feeds: an execution or a parameter (rosworker/configurations/feed.py)
        if kind != "data":
            if self.streams.feeds is None:
                raise IpcError("bad-request", "kind: this ROS worker streams topics only")
            result = self.streams.create(collection, entity_id, _string(task.args, "resource"), "", mode,
                                         _string(task.args, "interval", tuple(events.INTERVALS)),
                                         self._duration(task.args), client, _string(task.args, "kind"),
                                         task.args.get("target"))
            self.streams.when_saved(lambda: task.reply(result))
            return
        result = self.streams.create(collection, entity_id, _string(task.args, "resource"), _topic(task.args),
                                     mode, _string(task.args, "interval", tuple(events.INTERVALS)),
                                     self._duration(task.args), client)
        # Answered once it is in the restart state: it survives a ROS worker killed right after.
        self.streams.when_saved(lambda: task.reply(result))

    def sub_list(self, task: Task) -> None:
        task.reply({"items": self.streams.listing(*self._entity(task.args))})

    def sub_get(self, task: Task) -> None:
        task.reply(self.streams.get(*self._entity(task.args), _string(task.args, "id", limit=64)).wire())

    def sub_update(self, task: Task) -> None:
        interval = duration = None
        if task.args.get("interval") is not None:
            interval = _string(task.args, "interval", tuple(events.INTERVALS))
        if task.args.get("duration") is not None:
            duration = self._duration(task.args)
        result = self.streams.update(*self._entity(task.args), _string(task.args, "id", limit=64),
                                     interval, duration)
        self.streams.when_saved(lambda: task.reply(result))

    def sub_delete(self, task: Task) -> None:
        self.streams.delete(*self._entity(task.args), _string(task.args, "id", limit=64))
        self.streams.when_saved(lambda: task.reply({}))

    def debug_sleep(self, task: Task) -> None:
        time.sleep(_number(task.args, "seconds", 1.0, 0, 600))
        task.reply({})
