"""In-process pieces for unit tests of ``rosworker/``: a real ROS thread, and a node that is not rclpy's.

``RosThread`` runs a real :class:`rosworker.core.executor.RosExecutor` loop (its work
socket bound in a temporary runtime dir, its timers, its wake-up pipe) on a
thread of its own, and runs test code on that thread with :meth:`RosThread.call`,
as the ROS worker runs everything of ``rosworker/`` on its one ROS thread:

    with RosThread(tmp_path) as ros:
        registry = ros.call(make_registry, ros)
        ros.call(registry.create, ...)

``FakeNode`` answers the graph queries of ``rclpy.node.Node`` that
``rosworker/core/graph.py`` makes, from tables a test edits (``nodes``, ``endpoints``).
The objects are built as ``rosworker/main.py`` builds them; the real process is
tested through ``tests/support/rosworker.py`` and the gateway.
"""

from __future__ import annotations

import concurrent.futures
import threading
from collections.abc import Callable
from typing import Any

import zmq

from rosworker.core.task import Timer
from rosworker.subscriptions.registry import Subscription

CALL_TIMEOUT = 10.0  # seconds a call on the ROS thread may take before the test fails (a hang)


class RosThread:
    def __init__(self, runtime_dir, max_queue_depth: int = 64):
        from rosworker.core.executor import RosExecutor
        from rosworker.core.stats import Stats

        self.runtime_dir = str(runtime_dir)
        self.zctx = zmq.Context()
        self.stats = Stats(pool_cap=16, cold_wait_cap=4, watchdog_threshold_ms=5000)
        self.executor = RosExecutor(self.zctx, self.runtime_dir, self.stats, max_queue_depth)
        self.executor.bind()
        self._thread = threading.Thread(target=self.executor.run, name="test-ros-thread", daemon=True)

    def __enter__(self) -> RosThread:
        self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def call(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        """Run ``fn(*args, **kwargs)`` on the ROS thread; its result, or its exception raised here."""
        done: concurrent.futures.Future = concurrent.futures.Future()

        def run() -> None:
            try:
                done.set_result(fn(*args, **kwargs))
            except BaseException as exc:  # handed to the caller's thread
                done.set_exception(exc)

        self.executor.post(run)
        return done.result(CALL_TIMEOUT)

    def close(self) -> None:
        self.executor.stop()
        self._thread.join(CALL_TIMEOUT)
        assert not self._thread.is_alive(), "the ROS thread did not stop"
        self.executor.close()
        self.zctx.destroy(linger=0)


class FakeNode:
    """The graph as a node sees it: ``nodes`` [(name, namespace)], ``endpoints`` {(name, namespace):
    {"pub": [(topic, type)], "sub": [(topic, type)]}}; ``failing`` nodes raise on the per-node calls."""

    def __init__(self, name: str = "gw_sub", namespace: str = "/"):
        self.name, self.namespace = name, namespace
        self.nodes: list[tuple[str, str]] = [(name, namespace)]
        self.endpoints: dict[tuple[str, str], dict[str, list[tuple[str, str]]]] = {}
        self.failing: set[tuple[str, str]] = set()
        self.per_node_calls = 0  # get_{publisher,subscriber}_names_and_types_by_node, the expensive ones

    def add(self, fqn: str, pub=(), sub=()) -> None:
        namespace, _, name = fqn.rpartition("/")
        key = (name, namespace or "/")
        if key not in self.nodes:
            self.nodes.append(key)
        self.endpoints[key] = {"pub": list(pub), "sub": list(sub)}

    def remove(self, fqn: str) -> None:
        namespace, _, name = fqn.rpartition("/")
        key = (name, namespace or "/")
        self.nodes.remove(key)
        self.endpoints.pop(key, None)

    # ---- what rclpy.node.Node answers -------------------------------------------------------
    def get_name(self) -> str:
        return self.name

    def get_namespace(self) -> str:
        return self.namespace

    def get_node_names_and_namespaces(self) -> list[tuple[str, str]]:
        return list(self.nodes)

    def _all(self, kind: str):
        for key in self.nodes:
            yield from self.endpoints.get(key, {}).get(kind, [])

    def get_topic_names_and_types(self) -> list[tuple[str, list[str]]]:
        table: dict[str, list[str]] = {}
        for topic, type_ in [*self._all("pub"), *self._all("sub")]:
            types = table.setdefault(topic, [])
            if type_ not in types:
                types.append(type_)
        return sorted(table.items())

    def _by_node(self, kind: str, name: str, namespace: str) -> list[tuple[str, list[str]]]:
        self.per_node_calls += 1
        if (name, namespace) in self.failing:
            raise RuntimeError(f"node {name} not found")  # as rclpy says of a node that just left
        return [(t, [ty]) for t, ty in self.endpoints.get((name, namespace), {}).get(kind, [])]

    def get_publisher_names_and_types_by_node(self, name: str, namespace: str):
        return self._by_node("pub", name, namespace)

    def get_subscriber_names_and_types_by_node(self, name: str, namespace: str):
        return self._by_node("sub", name, namespace)

    def count_publishers(self, topic: str) -> int:
        return sum(t == topic for t, _ in self._all("pub"))

    def count_subscribers(self, topic: str) -> int:
        return sum(t == topic for t, _ in self._all("sub"))


class TimerExecutor:
    """The executor as a feed sees it: ``call_later`` keeps its timers (not run), ``guarded`` runs at once,
    and the test runs the feed's one armed timer with :meth:`fire`."""

    def __init__(self):
        self.timers: list[Timer] = []

    def call_later(self, delay, fn):
        timer = Timer(delay, fn)
        self.timers.append(timer)
        return timer

    def guarded(self, _where, fn, *args):
        return fn(*args)

    def fire(self):
        """Run the one live timer (a feed keeps exactly one armed)."""
        live = [t for t in self.timers if not t.cancelled]
        self.timers = []
        assert len(live) == 1, live
        live[0].fn()


class FakeEvents:
    """The core's events channel: what the feed publishes."""

    def __init__(self):
        self.frames: list[tuple[bytes, dict, bytes]] = []

    def publish(self, key, meta, data=b"{}"):
        self.frames.append((key, meta, data))


def feed_subscription(kind: str, target: dict, interval: str = "fast"):
    """A cyclic subscription of ``kind`` (a sampler's name) on ``target``, as the registry hands it to a feed."""
    return Subscription(id="sub_0123456789abcdef", collection="apps", entity_id="tuner", resource="/r",
                        topic="", bytes="array", interval=interval, duration=60, created_at_ns=0, kind=kind,
                        target=target)
