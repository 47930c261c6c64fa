"""Prometheus metrics: ``GET /metrics`` (beside ``/api/v1``, never rate-limited).

Three sources, all in the ``sovd_`` namespace:

- **The HTTP workers** (this module's :class:`HttpMetrics`): requests by route
  template, method and status; latency by route template; open SSE streams;
  frames sent and dropped; requests refused by the rate limiter.  Route
  labels are Flask's rule templates (``/api/v1/apps/<entity_id>``), never raw
  paths (``unmatched`` when no route matched), and methods outside a fixed
  set are ``other``: the label sets are bounded whatever clients send.
  Under gunicorn the supervisor sets ``PROMETHEUS_MULTIPROC_DIR`` to
  ``<runtime_dir>/metrics`` (0700, emptied at start-up) before any worker
  starts, so prometheus_client keeps each worker's values in per-pid mmap
  files there and a scrape, served by any worker, adds every worker's files
  up (``MultiProcessCollector``).  When a worker exits, gunicorn's
  ``child_exit`` hook (``app/gunicorn_conf.py``) marks it dead: its live
  gauges go, its counters stay in the sums.  Without the variable (the Flask
  test client) the values are this process's own.
- **The ROS worker** (:class:`RosWorkerCollector`): every counter of its
  ``stats`` answer (``x-medkit-data-provider``, ``x-medkit-subscription-executor``,
  the cyclic subscriptions, evictions by cause, commands), asked once per
  scrape on the control socket with a deadline of at most ``ipc_timeout``.
  ``sovd_ros_worker_up`` is 0, and nothing else of it is exported, while it
  does not answer.
- **The supervisor** (:class:`SupervisorCollector`): ROS-worker restarts and
  the time since the running ROS worker started, from the small state file
  the supervisor rewrites at each start (``common/runfiles.py``; the supervisor
  never loads gevent, Flask or prometheus_client).

Who calls what: the request hooks run on each request's greenlet; the
collectors run inside the ``/metrics`` request.  Nothing is made at import
time: :func:`http` makes the metric objects on first use, in the worker.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from typing import Any

from flask import Blueprint, Flask, Response, current_app, request

from common import runfiles

from . import rosclient

# Latency buckets (seconds): 0.25 ms (a cached answer on a quiet machine) to 5 s (a cold read's
# sample_timeout plus IPC), about three per decade.
BUCKETS = (0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0)
METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "DELETE", "PATCH", "OPTIONS"})
UNMATCHED = "unmatched"

bp = Blueprint("metrics", __name__)


class HttpMetrics:
    """The HTTP side's metric objects (one set per process; not in any global registry)."""

    def __init__(self) -> None:
        from prometheus_client import Counter, Gauge, Histogram

        self.requests = Counter(
            "sovd_http_requests", "HTTP requests answered, by route template, method and status",
            ["route", "method", "status"], registry=None)
        self.latency = Histogram(
            "sovd_http_request_duration_seconds",
            "Time from the start of a request to its response (an event stream: to its headers), "
            "by route template", ["route"], buckets=BUCKETS, registry=None)
        self.streams_open = Gauge(
            "sovd_http_streams_open", "Server-Sent Event streams open now (all HTTP workers)",
            registry=None, multiprocess_mode="livesum")
        self.frames_sent = Counter(
            "sovd_http_stream_frames_sent", "SSE frames written to clients", registry=None)
        self.frames_dropped = Counter(
            "sovd_http_stream_frames_dropped",
            "SSE frames dropped for clients that did not read fast enough (the oldest go first)",
            registry=None)
        self.rate_limited = Counter(
            "sovd_http_rate_limited", "Requests refused with 429 by the rate limiter, by the bucket "
            "that was empty (client or global)", ["scope"], registry=None)

        # (route, method, status) -> (request counter, latency histogram) of that label set:
        # prometheus_client's labels() costs more than the increment itself.
        self._children: dict[tuple[str, str, int], tuple[Any, Any]] = {}

    def observe(self, route: str, method: str, status: int, seconds: float) -> None:
        """One request answered: count it and time it (labels bounded: templates, known methods)."""
        key = (route, method if method in METHODS else "other", status)  # bounded, whatever is sent
        children = self._children.get(key)
        if children is None:
            children = self._children[key] = (self.requests.labels(route, key[1], str(status)),
                                               self.latency.labels(route))
        children[0].inc()
        children[1].observe(seconds)

    def families(self):
        for metric in (self.requests, self.latency, self.streams_open, self.frames_sent,
                       self.frames_dropped, self.rate_limited):
            yield from metric.collect()


_http: HttpMetrics | None = None


def http() -> HttpMetrics:
    """This process's HTTP metrics, made on first use (after the fork)."""
    global _http
    if _http is None:
        _http = HttpMetrics()
    return _http


def multiproc_dir() -> str | None:
    path = os.environ.get(runfiles.MULTIPROC_ENV)
    return path if path and os.path.isdir(path) else None


# ---- request hooks ------------------------------------------------------------------------------
T0 = "sovd.metrics.t0"  # in the request's environ: when it began


def _start() -> None:
    request.environ[T0] = time.perf_counter()


def _finish(response: Response) -> Response:
    req = request._get_current_object()
    t0 = req.environ.pop(T0, None)
    if t0 is None:
        return response
    rule = req.url_rule
    http().observe(rule.rule if rule is not None else UNMATCHED, req.method, response.status_code,
                   time.perf_counter() - t0)
    return response


def rate_limited(scope: str) -> None:
    """Called by the rate limiter for each 429 (``scope``: ``client`` or ``global``)."""
    http().rate_limited.labels(scope).inc()


# ---- the ROS worker, at scrape time -------------------------------------------------------------
# (section, key, metric name, type, help, scale); counters get "_total" from prometheus_client.
ROS_FIELDS: tuple[tuple[str, str, str, str, str, float], ...] = (
    ("data_provider", "pool_size", "sovd_ros_pool_size", "gauge", "Topics pooled (subscribed) now", 1),
    ("data_provider", "pool_cap", "sovd_ros_pool_cap", "gauge", "Most topics the pool holds (max_pool_size)", 1),
    ("data_provider", "pool_hits", "sovd_ros_pool_hits", "counter", "Reads of a topic already pooled", 1),
    ("data_provider", "pool_misses", "sovd_ros_pool_misses", "counter",
     "Reads that had to subscribe to the topic first", 1),
    ("data_provider", "evictions_total", "sovd_ros_pool_evictions_all", "counter",
     "Topics dropped from the pool, any cause (by cause: sovd_ros_pool_evictions_total)", 1),
    ("data_provider", "type_change_events", "sovd_ros_type_changes", "counter",
     "Pooled topics dropped because their message type changed", 1),
    ("data_provider", "graph_events_received", "sovd_ros_graph_changes", "counter",
     "Changes of the ROS graph seen", 1),
    ("data_provider", "concurrent_cold_waits", "sovd_ros_cold_waits", "gauge",
     "Readers waiting for a cold topic's first message now", 1),
    ("data_provider", "cold_wait_cap", "sovd_ros_cold_wait_cap", "gauge",
     "Readers allowed to wait on cold topics at once (0: no cap)", 1),
    ("data_provider", "unsupported_type_count", "sovd_ros_unsupported_type_reads", "counter",
     "Reads of topics whose message type is not installed", 1),
    ("data_provider", "undecodable_messages", "sovd_ros_undecodable_messages", "counter",
     "Messages that did not decode as their type", 1),
    ("data_provider", "pool_bytes", "sovd_ros_pool_bytes", "gauge", "Bytes of kept messages (raw and JSON)", 1),
    ("data_provider", "pool_bytes_cap", "sovd_ros_pool_bytes_cap", "gauge", "Byte budget of the pool", 1),
    ("executor", "degraded", "sovd_ros_degraded", "gauge",
     "1 while a ROS task has run longer than the watchdog threshold", 1),
    ("executor", "queue_depth", "sovd_ros_queue_depth", "gauge", "Commands queued for the ROS thread now", 1),
    ("executor", "queue_max_depth_observed", "sovd_ros_queue_depth_max", "gauge",
     "Deepest the command queue has been", 1),
    ("executor", "queue_dropped", "sovd_ros_queue_rejected", "counter",
     "Commands refused because the queue was full (backpressure)", 1),
    ("executor", "last_task_latency_us", "sovd_ros_last_task_seconds", "gauge",
     "Time the last ROS task took", 1e-6),
    ("executor", "max_task_latency_us", "sovd_ros_max_task_seconds", "gauge", "Longest ROS task so far", 1e-6),
    ("executor", "current_task_age_ms", "sovd_ros_current_task_seconds", "gauge",
     "Time the running ROS task has taken so far (0 while idle)", 1e-3),
    ("executor", "watchdog_trips", "sovd_ros_watchdog_trips", "counter",
     "Times a ROS task ran past the watchdog threshold", 1),
    ("executor", "loop_errors", "sovd_ros_loop_errors", "counter",
     "Failures contained on the ROS thread outside any request", 1),
    ("streams", "active_subscriptions", "sovd_ros_subscriptions", "gauge", "Cyclic subscriptions held now", 1),
    ("streams", "max_subscriptions", "sovd_ros_subscriptions_cap", "gauge",
     "Most cyclic subscriptions held at once (max_subscriptions)", 1),
    ("streams", "subscriptions_created", "sovd_ros_subscriptions_created", "counter",
     "Cyclic subscriptions created", 1),
    ("streams", "subscriptions_expired", "sovd_ros_subscriptions_expired", "counter",
     "Cyclic subscriptions that ran out", 1),
    ("streams", "frames_published", "sovd_ros_stream_frames_published", "counter",
     "Stream frames the ROS worker sent to the HTTP workers", 1),
    ("details", "publishers", "sovd_ros_publishers", "gauge", "Pooled publishers (PUT) now", 1),
    ("details", "publishes_total", "sovd_ros_publishes", "counter", "Messages published (PUT)", 1),
    ("details", "publishers_expired", "sovd_ros_publishers_expired", "counter",
     "Pooled publishers dropped after being unused", 1),
    ("details", "publishes_waiting", "sovd_ros_publishes_waiting", "gauge",
     "Publishes waiting for their subscribers to match now", 1),
    ("details", "pool_json_drops", "sovd_ros_pool_json_drops", "counter",
     "Cached JSON texts dropped for the byte budget", 1),
    ("details", "ipc_dropped_frames", "sovd_ros_ipc_dropped_frames", "counter",
     "IPC frames dropped because they were not requests", 1),
)


def _number(value: Any) -> float | None:
    if isinstance(value, bool):
        return float(value)
    if isinstance(value, int | float):
        return float(value)
    return None


class RosWorkerCollector:
    """The ROS worker's counters, asked once per scrape (``stats``, deadline ≤ ``ipc_timeout``)."""

    def __init__(self, ros: rosclient.RosClient, timeout: float):
        self.ros = ros
        self.timeout = timeout

    def collect(self) -> Iterator[Any]:
        from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

        alive, stats = self.ros.stats(timeout=self.timeout)
        yield GaugeMetricFamily("sovd_ros_worker_up", "1 when the ROS worker answered this scrape's "
                                "stats request in time, else 0 (its other metrics are then left out)",
                                value=1.0 if alive else 0.0)
        if not alive or not isinstance(stats, dict):
            return
        for section, key, name, kind, help_text, scale in ROS_FIELDS:
            part = stats.get(section)
            value = _number(part.get(key)) if isinstance(part, dict) else None
            if value is None:
                continue
            family = CounterMetricFamily if kind == "counter" else GaugeMetricFamily
            yield family(name, help_text, value=value * scale)
        executor = stats.get("executor") if isinstance(stats.get("executor"), dict) else {}
        tasks = CounterMetricFamily("sovd_ros_tasks", "ROS tasks run, by outcome", labels=["outcome"])
        for outcome, key in (("completed", "tasks_completed"), ("failed", "tasks_failed")):
            value = _number(executor.get(key))
            if value is not None:
                tasks.add_metric([outcome], value)
        yield tasks
        details = stats.get("details") if isinstance(stats.get("details"), dict) else {}
        yield from self._labelled(details)

    def _labelled(self, details: dict) -> Iterator[Any]:
        from prometheus_client.core import CounterMetricFamily

        evictions = CounterMetricFamily("sovd_ros_pool_evictions", "Topics dropped from the pool, by cause "
                                        "(graph, type_change, lru, idle, qos_rebuild, manual, shutdown, bytes)",
                                        labels=["cause"])
        for cause, value in sorted((details.get("evictions") or {}).items()):
            if _number(value) is not None:
                evictions.add_metric([str(cause)], _number(value))
        yield evictions
        count = CounterMetricFamily("sovd_ros_commands", "Queued commands run on the ROS thread, by command",
                                    labels=["command"])
        seconds = CounterMetricFamily("sovd_ros_command_seconds", "Time the ROS thread spent on queued "
                                      "commands, by command", labels=["command"])
        for command, totals in sorted((details.get("commands") or {}).items()):
            if isinstance(totals, dict) and _number(totals.get("count")) is not None:
                count.add_metric([str(command)], _number(totals["count"]))
                seconds.add_metric([str(command)], (_number(totals.get("time_us")) or 0.0) / 1e6)
        yield count
        yield seconds
        ticks = CounterMetricFamily("sovd_ros_stream_ticks", "Rounds of the stream timers, by interval",
                                    labels=["interval"])
        for interval, value in sorted((details.get("ticks") or {}).items()):
            if _number(value) is not None:
                ticks.add_metric([str(interval)], _number(value))
        yield ticks


# ---- the supervisor ------------------------------------------------------------------------------
class SupervisorCollector:
    """ROS-worker restarts and the time since the running one started, from the supervisor's state file."""

    def __init__(self, runtime_dir: str):
        self.runtime_dir = runtime_dir

    def collect(self) -> Iterator[Any]:
        from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

        state = runfiles.read_supervisor_state(self.runtime_dir)
        if state is None:
            return  # not under the supervisor (a test app)
        restarts = _number(state.get("ros_worker_restarts"))
        started = _number(state.get("ros_worker_started_at"))
        if restarts is not None:
            yield CounterMetricFamily("sovd_supervisor_ros_worker_restarts", "ROS worker restarts by the "
                                      "supervisor since the gateway started", value=restarts)
        if started is not None:
            yield GaugeMetricFamily("sovd_supervisor_ros_worker_start_time_seconds", "When the running ROS "
                                    "worker was started (first start or last restart), Unix time",
                                    value=started)
            yield GaugeMetricFamily("sovd_supervisor_ros_worker_seconds_since_start", "Seconds since the "
                                    "running ROS worker was started (its first start or the last restart)",
                                    value=max(0.0, time.time() - started))


class _ThisProcess:
    """The HTTP metrics of this process alone (no PROMETHEUS_MULTIPROC_DIR: the Flask test client)."""

    def collect(self):
        return http().families()


@bp.get("/metrics")
def metrics() -> Response:
    from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
    from prometheus_client.multiprocess import MultiProcessCollector

    cfg = current_app.config["SOVD"]
    http()  # this worker's own series exist (at zero) even before its first request is counted
    registry = CollectorRegistry(auto_describe=False)
    path = multiproc_dir()
    if path is not None:
        MultiProcessCollector(registry, path=path)
    else:
        registry.register(_ThisProcess())
    registry.register(RosWorkerCollector(rosclient.get(), min(rosclient.STATS_TIMEOUT_S, cfg.ipc_timeout)))
    registry.register(SupervisorCollector(cfg.runtime_dir))
    return Response(generate_latest(registry), mimetype=None, content_type=CONTENT_TYPE_LATEST)


def init_app(app: Flask) -> None:
    """Time and count every request (call right after ``requestid.init_app``); serve ``/metrics``."""
    app.before_request(_start)
    app.after_request(_finish)
    app.register_blueprint(bp)
