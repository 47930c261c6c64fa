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
  ``stats`` answer, as ``ipc/counters.py`` declares them (``x-medkit-data-provider``, ``x-medkit-subscription-executor``,
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

import glob
import json
import os
import time
from collections.abc import Iterator
from typing import Any

from flask import Blueprint, Flask, Response, current_app, request

from common import runfiles
from ipc import counters

from . import rosclient
from .family import plugged

# Latency buckets (seconds): 0.25 ms (a cached answer on a quiet machine) to 5 s (a cold read's
# sample_timeout plus IPC), about three per decade.
BUCKETS = (0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0)
METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "DELETE", "PATCH", "OPTIONS"})
UNMATCHED = "unmatched"
# app.extensions[COLLECTORS]: what a family adds to a scrape (callables, each making a collector per scrape)
COLLECTORS = "sovd_metrics_collectors"

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
        # The stream counters of x-medkit-streams (ipc/counters.py): /health sums them too.
        streams = {c.name: c for c in counters.HTTP_COUNTERS}
        self.streams_open = Gauge(streams["open_streams"].metric, streams["open_streams"].help,
                                  registry=None, multiprocess_mode="livesum")
        self.frames_sent = Counter(streams["frames_sent"].metric, streams["frames_sent"].help, registry=None)
        self.frames_dropped = Counter(streams["frames_dropped"].metric, streams["frames_dropped"].help,
                                      registry=None)
        # Every other counter the HTTP workers keep (ipc/counters.py, origin HTTP), e.g. the lock
        # refusals of x-medkit-locks: one Counter each, by its declared name.
        made = {"open_streams", "frames_sent", "frames_dropped"}
        self.declared = {c.name: Counter(c.metric, c.help, registry=None)
                         for c in counters.HTTP_COUNTERS if c.kind == counters.COUNTER and c.name not in made}
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
                       self.frames_dropped, self.rate_limited, *self.declared.values()):
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


# The metric files of the counters and of the live-summed gauges: those of the stream counters.
STREAM_FILES = ("counter_*.db", "gauge_livesum_*.db")
# Seconds a worker reuses the sums it read (reading them costs ~0.1 ms for two workers, a tenth
# of a /health; they were up to a second old when the HTTP workers reported them every second).
STREAM_TOTALS_TTL = 0.25
_stream_totals: tuple[float, dict[str, int]] = (float("-inf"), {})


def stream_totals() -> dict[str, int]:
    """``open_streams``, ``frames_sent``, ``frames_dropped`` (and every other counter of origin HTTP,
    such as ``lock_refusals``) of every HTTP worker (``/health``).

    The sums a scrape makes (open streams of the live workers, frames of every worker since the
    gateway started), read from the multiprocess directory; without it (the Flask test client)
    this process's own.  Only the entries of these three metrics are decoded (the files also
    hold every request counter), and the sums are kept for :data:`STREAM_TOTALS_TTL`.
    """
    global _stream_totals
    names = {c.metric: c.name for c in counters.HTTP_COUNTERS}
    totals = dict.fromkeys(names.values(), 0)
    path = multiproc_dir()
    if path is None:
        for family in http().families():
            for sample in family.samples:
                if family.name in names and sample.name in (family.name, family.name + "_total"):
                    totals[names[family.name]] += int(sample.value)
        return totals
    now = time.monotonic()
    if now - _stream_totals[0] < STREAM_TOTALS_TTL:
        return dict(_stream_totals[1])
    from prometheus_client.mmap_dict import MmapedDict

    prefixes = tuple(f'["{metric}", "{metric}' for metric in names)  # a key: [metric, sample, labels, help]
    for pattern in STREAM_FILES:
        for file in glob.glob(os.path.join(path, pattern)):
            try:
                entries = MmapedDict.read_all_values_from_file(file)
            except FileNotFoundError:
                continue  # a live gauge's file, removed as its worker was marked dead
            for key, value, _timestamp, _pos in entries:
                if key.startswith(prefixes):
                    metric, sample = json.loads(key)[:2]
                    if sample in (metric, metric + "_total"):  # not _created
                        totals[names[metric]] += int(value)
    _stream_totals = (now, totals)
    return dict(totals)


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
# Its counters exported one metric each (declared in ipc/counters.py; "_total" is prometheus_client's).
ROS_FIELDS = tuple(c for c in counters.ROS_COUNTERS
                   if c.metric and c.kind in (counters.COUNTER, counters.GAUGE, counters.FLAG))


def number(value: Any) -> float | None:
    if isinstance(value, bool):
        return float(value)
    if isinstance(value, int | float):
        return float(value)
    return None


class RosWorkerCollector:
    """The ROS worker's counters, asked once per scrape (``stats``, deadline ≤ ``ipc_timeout``)."""

    def __init__(self, ros: rosclient.RosClient, timeout: float, families: tuple = ()):
        self.ros = ros
        self.timeout = timeout
        self.families = families

    def collect(self) -> Iterator[Any]:
        from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

        alive, stats = self.ros.stats(timeout=self.timeout)
        yield GaugeMetricFamily("sovd_ros_worker_up", "1 when the ROS worker answered this scrape's "
                                "stats request in time, else 0 (its other metrics are then left out)",
                                value=1.0 if alive else 0.0)
        if not alive or not isinstance(stats, dict):
            return
        families: dict[str, Any] = {}  # a metric made of several counters: one family, a sample each
        for c in ROS_FIELDS:
            part = stats.get(c.section)
            value = number(part.get(c.name)) if isinstance(part, dict) else None
            family = CounterMetricFamily if c.kind == counters.COUNTER else GaugeMetricFamily
            if c.label is None:
                if value is not None:
                    yield family(c.metric, c.help, value=value * c.scale)
                continue
            label, label_value = c.label.split("=")
            grouped = families.get(c.metric)
            if grouped is None:
                grouped = families[c.metric] = family(c.metric, counters.FAMILY_HELP[c.metric], labels=[label])
            if value is not None:
                grouped.add_metric([label_value], value * c.scale)
        yield from families.values()
        details = stats.get("details") if isinstance(stats.get("details"), dict) else {}
        yield from self._labelled(details)
        for family in self.families:  # what a family exports besides its counters (faults by severity)
            if family.metrics is not None:
                yield from family.metrics(stats)

    def _labelled(self, details: dict) -> Iterator[Any]:
        """The details' maps: one counter family per map (two for a command's count and time)."""
        from prometheus_client.core import CounterMetricFamily

        for c in counters.section("details", counters.ROS):
            values = details.get(c.name)
            values = values if isinstance(values, dict) else {}
            if c.kind == counters.BY:
                family = CounterMetricFamily(c.metric, c.help, labels=[c.label])
                for key, value in sorted(values.items()):
                    if number(value) is not None:
                        family.add_metric([str(key)], number(value))
                yield family
            elif c.kind == counters.TIMINGS:
                seconds_name, seconds_help = counters.TIMINGS_SECONDS[c.metric]
                count = CounterMetricFamily(c.metric, c.help, labels=[c.label])
                seconds = CounterMetricFamily(seconds_name, seconds_help, labels=[c.label])
                for key, totals in sorted(values.items()):
                    if isinstance(totals, dict) and number(totals.get("count")) is not None:
                        count.add_metric([str(key)], number(totals["count"]))
                        seconds.add_metric([str(key)], (number(totals.get("time_us")) or 0.0) / 1e6)
                yield count
                yield seconds


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
        restarts = number(state.get("ros_worker_restarts"))
        started = number(state.get("ros_worker_started_at"))
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
    if not cfg.fleet_aggregate:  # the fleet gateway runs no ROS worker (app/fleet/)
        registry.register(RosWorkerCollector(rosclient.get(), min(rosclient.STATS_TIMEOUT_S, cfg.ipc_timeout),
                                             plugged(current_app)))
    registry.register(SupervisorCollector(cfg.runtime_dir))
    for make in current_app.extensions.get(COLLECTORS, ()):
        registry.register(make())
    return Response(generate_latest(registry), mimetype=None, content_type=CONTENT_TYPE_LATEST)


def init_app(app: Flask) -> None:
    """Time and count every request (call right after ``requestid.init_app``); serve ``/metrics``."""
    app.before_request(_start)
    app.after_request(_finish)
    app.register_blueprint(bp)
