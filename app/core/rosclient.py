"""The HTTP worker's side of the ROS worker: one client per process and its caches.

Before fork / after fork: :func:`init_app` only records settings.  The
:class:`~ipc.client.RosWorkerClient` (and with it the ZeroMQ context and
sockets) is made on first use in the process that uses it; a process that
finds one made by another pid (it was forked) makes its own.

Caches, per process and thread-safe:

- the ROS graph and the entities built from it, keyed by the worker's
  ``generation``.  The worker is asked (``graph`` with ``since``) at most once
  per ``GRAPH_REFRESH_S`` (0.2 s); other requests reuse the cached entities.
  ``since`` is only sent while the cache is fresh (asked less than
  ``GRAPH_SINCE_MAX_AGE_S`` ago), because a restarted ROS worker counts its
  generations from 0 again and could answer "unchanged" for a different graph.
- ``type_info`` per message type (a type that is not installed is asked again
  after ``TYPE_INFO_NEGATIVE_TTL_S``), at most ``TYPE_INFO_CACHE_MAX`` types,
  least recently used dropped first.  The data listing and every data read
  use it, so a warm read adds no round trip for its ``type_info``.
- the last ``stats`` answer, so that ``/health`` can show last known counters
  while the ROS worker is down.
"""

from __future__ import annotations

import collections
import contextlib
import functools
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import orjson
from flask import Flask, current_app

from common.process import PerProcess
from ipc.client import RosWorkerClient
from ipc.errors import IpcError

from . import entities, requestid

log = logging.getLogger("sovd.http.rosclient")

EXTENSION = "sovd_rosclient"
GRAPH_REFRESH_S = 0.2
GRAPH_SINCE_MAX_AGE_S = 1.0
TYPE_INFO_NEGATIVE_TTL_S = 30.0
TYPE_INFO_CACHE_MAX = 1024
STATS_TIMEOUT_S = 0.3
STATS_CONNECT_WAIT_S = 0.1
# Errors after which a cached graph is still served (the worker is alive but busy).
STALE_OK = ("deadline-exceeded", "backpressure")
STALE_MAX_AGE_S = 10.0


class RosClient:
    def __init__(self, runtime_dir: str, ipc_timeout: float, build: Callable[[dict], entities.Entities],
                 graph_refresh: float = GRAPH_REFRESH_S):
        self.runtime_dir = runtime_dir
        self.ipc_timeout = ipc_timeout
        self.graph_refresh = graph_refresh
        self._build = build
        # A partial, not a closure over self: no reference cycle, so an unclosed client (and its
        # ZeroMQ context) is freed by reference counting, sockets first, never by the cyclic
        # collector, which may finalize the context first and block in its term().
        self._client: PerProcess[RosWorkerClient] = PerProcess(
            functools.partial(RosWorkerClient.for_runtime_dir, runtime_dir), RosWorkerClient.close)
        # graph cache
        self._graph_lock = threading.Lock()
        self._entities: entities.Entities | None = None
        self._checked = 0.0       # monotonic time of the last graph answer (or tolerated failure)
        self._fetched = 0.0       # monotonic time of the last graph answer
        # type_info cache: type -> (info or None, expires at)
        self._types: collections.OrderedDict[str, tuple[dict[str, Any] | None, float, bytes | None]] = \
            collections.OrderedDict()
        self._last_stats: dict[str, Any] | None = None

    # ------------------------------------------------------------------ transport

    @property
    def client(self) -> RosWorkerClient:
        return self._client.get()

    def close(self) -> None:
        """Close this process's client (its sockets and ZeroMQ context), e.g. when a test ends."""
        self._client.reset()

    def call(self, cmd: str, args: dict[str, Any] | None = None, timeout: float | None = None,
             **kw: Any) -> dict[str, Any]:
        """One command; inside an HTTP request its ``X-Request-Id`` goes along (``app/core/requestid.py``)."""
        return self.client.call(cmd, args, self.ipc_timeout if timeout is None else timeout,
                                request_id=requestid.current(), **kw)

    # ------------------------------------------------------------------ graph

    def entities(self, checked_since: float | None = None) -> entities.Entities:
        """The entity index of the current ROS graph (at most ``graph_refresh`` old).

        ``checked_since`` (a ``time.monotonic()`` value): the graph must have been asked for at or
        after it.  A "not found" is confirmed this way before it is answered: the HTTP workers
        cache the graph each on its own, so a client that just saw an entity through one worker
        must not be told by the other that it does not exist.
        """
        cached = self._entities
        if checked_since is not None and cached is not None and self._checked < checked_since:
            with self._graph_lock_for(self.ipc_timeout + 1.0):
                if self._checked < checked_since:
                    self._checked = 0.0     # forces _refresh to ask (with ``since``: cheap if unchanged)
                return self._refresh()
        if cached is not None and time.monotonic() - self._checked < self.graph_refresh:
            return cached
        if cached is not None and time.monotonic() - self._checked < 2 * self.graph_refresh:
            # Someone else is refreshing a cache that was current a moment ago: use it.
            if not self._graph_lock.acquire(blocking=False):
                return cached
        elif not self._graph_lock.acquire(timeout=self.ipc_timeout + 1.0):
            # An old cache (this process was not asked for a while) is not served while a fresher
            # one is on its way: concurrent requests wait for that refresh, or fail like it would.
            raise IpcError("deadline-exceeded", "The ROS graph is not available in time")
        try:
            return self._refresh()
        finally:
            self._graph_lock.release()

    @contextlib.contextmanager
    def _graph_lock_for(self, timeout: float):
        if not self._graph_lock.acquire(timeout=timeout):
            raise IpcError("deadline-exceeded", "The ROS graph is not available in time")
        try:
            yield
        finally:
            self._graph_lock.release()

    def _refresh(self) -> entities.Entities:
        cached = self._entities
        now = time.monotonic()
        if cached is not None and now - self._checked < self.graph_refresh:
            return cached
        args = {}
        if cached is not None and now - self._fetched < GRAPH_SINCE_MAX_AGE_S:
            args["since"] = cached.generation
        try:
            answer = self.call("graph", args)
        except IpcError as exc:
            if cached is not None and exc.code in STALE_OK and now - self._fetched < STALE_MAX_AGE_S:
                log.debug("graph refresh failed (%s); serving generation %s", exc.code, cached.generation)
                self._checked = time.monotonic()
                return cached
            self._entities = None
            raise
        now = time.monotonic()
        if answer.get("unchanged") is True and cached is not None and "since" in args \
                and answer.get("generation") == cached.generation:
            self._checked = self._fetched = now
            return cached
        if not isinstance(answer.get("nodes"), list):
            raise IpcError("internal", "The ROS worker answered 'graph' without nodes")
        built = self._build(answer)
        self._entities = built
        self._checked = self._fetched = now
        return built

    # ------------------------------------------------------------------ type_info

    def cached_type_info_json(self, type_name: str) -> bytes | None:
        """:meth:`type_info_json` from the cache only (never a round trip): ``b""`` for a type
        known not to be installed, None when the cache does not know the type (or it expired)."""
        hit = self._types.get(type_name)
        if hit is None or hit[1] <= time.monotonic():
            return None
        return hit[2] if hit[2] is not None else b""

    def type_info_json(self, type_name: str, timeout: float | None = None) -> bytes | None:
        """:meth:`type_info` already encoded as JSON (encoded once per type), or None."""
        hit = self._types.get(type_name)
        if hit is None or hit[1] <= time.monotonic():
            self.type_info(type_name, timeout)
            hit = self._types.get(type_name)
        return hit[2] if hit is not None else None

    def type_info(self, type_name: str, timeout: float | None = None) -> dict[str, Any] | None:
        """``{schema, default_value}`` of a message type, or None when it is not installed.

        Raises :class:`IpcError` only for transport trouble (the caller may
        then leave the information out).
        """
        hit = self._types.get(type_name)
        if hit is not None and hit[1] > time.monotonic():
            with contextlib.suppress(KeyError):  # another greenlet may have dropped it meanwhile
                self._types.move_to_end(type_name)
            return hit[0]
        try:
            info = self.call("type_info", {"type": type_name}, timeout)
            value = {"schema": info.get("schema"), "default_value": info.get("default_value")}
            self._remember_type(type_name, value, float("inf"))
            return value
        except IpcError as exc:
            if exc.code in ("type-not-installed", "invalid-type"):
                self._remember_type(type_name, None, time.monotonic() + TYPE_INFO_NEGATIVE_TTL_S)
                return None
            raise

    def _remember_type(self, type_name: str, value: dict[str, Any] | None, expires: float) -> None:
        self._types[type_name] = (value, expires, None if value is None else orjson.dumps(value))
        self._types.move_to_end(type_name)
        while len(self._types) > TYPE_INFO_CACHE_MAX:
            self._types.popitem(last=False)

    # ------------------------------------------------------------------ stats

    def stats(self, timeout: float = STATS_TIMEOUT_S) -> tuple[bool, dict[str, Any] | None]:
        """``(alive, stats)``: a fresh answer, or ``(False, last known answer or None)``.

        Uses a short deadline: ``stats`` is answered by the worker's IPC thread
        at once, so a worker that does not answer in time is not alive.
        """
        try:
            answer = self.call("stats", timeout=timeout,
                               connect_wait=min(STATS_CONNECT_WAIT_S, timeout))
        except IpcError:
            return False, self._last_stats
        self._last_stats = answer
        return True, answer


def init_app(app: Flask) -> None:
    cfg = app.config["SOVD"]
    host = entities.host_info(app.config.get("SOVD_HOSTNAME"))
    app.extensions[EXTENSION] = RosClient(
        cfg.runtime_dir, cfg.ipc_timeout, lambda graph: entities.build(graph, host),
        graph_refresh=app.config.get("SOVD_GRAPH_REFRESH_S", GRAPH_REFRESH_S),
    )


def get() -> RosClient:
    return current_app.extensions[EXTENSION]
