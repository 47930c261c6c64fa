"""What every reliability scenario shares: scale, HTTP clients, load threads, answer checks, figures.

Scale: ``SOVD_RELIABILITY=long`` (``make reliability``) runs the long form of
every scenario; anything else (``make test``) the short form.  :func:`scaled`
picks a number for the current form.

Clients: :class:`Client` is one keep-alive ``http.client`` connection with a
timeout on every socket operation; it sends the path exactly as written (no
re-quoting), so hostile paths reach the server as the test spells them.
:class:`Load` runs N such clients on threads until a duration or a request
count is reached and keeps one :class:`Answer` per request.  :class:`HealthProbe`
polls ``/health`` on its own connection all the while.

Checks: :func:`problem` says what is wrong with an answer according to
the REST contract (medkit's: JSON error bodies with a known ``error_code``, vendor
errors with their ``vendor_code``, ``Retry-After`` on 503), or None.

Figures: :func:`record` adds one row to :data:`FIGURES`; ``conftest.py``
prints the table at the end of the session and writes it as JSON to the
temp dir.  Timing goes into figures; assertions only catch hangs.
"""

from __future__ import annotations

import collections
import http.client
import json
import os
import random
import socket
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import psutil

MODE = "long" if os.environ.get("SOVD_RELIABILITY", "short").strip().lower() == "long" else "short"
LONG = MODE == "long"


def scaled(short: Any, long: Any) -> Any:
    """``short`` under ``make test``, ``long`` under ``make reliability``."""
    return long if LONG else short


# ---------------------------------------------------------------------------------- contract
ERROR_CODES = {
    "invalid-request", "invalid-parameter", "entity-not-found", "resource-not-found",
    "internal-error", "not-implemented", "service-unavailable", "not-responding", "vendor-error",
    "unauthorized", "forbidden", "payload-too-large", "rate-limit-exceeded",
    "operation-not-found", "precondition-not-fulfilled",  # operations (medkit's codes)
    "lock-broken",  # a write to an entity another client holds the lock of (medkit's code)
}
# vendor_code -> the HTTP status it travels with (ipc/errors.py, as medkit sends them)
VENDOR_CODES = {
    "x-medkit-cold-wait-cap-exceeded": 503,
    "x-medkit-gateway-shutdown": 503,
    "x-medkit-ros-worker-unavailable": 503,
    "x-medkit-ros-worker-backpressure": 503,
    "x-medkit-pool-busy": 503,
    "x-medkit-message-undecodable": 502,
    # cyclic subscriptions' refusals (app/subscriptions/routes.py)
    "x-medkit-invalid-resource-uri": 400,
    "x-medkit-entity-mismatch": 400,
    "x-medkit-collection-not-supported": 400,
    "x-medkit-unsupported-protocol": 400,
    "x-medkit-subscribe-failed": 500,
    "x-medkit-publish-failed": 500,
    # operations and configurations (app/core/errors.py)
    "x-medkit-ros2-service-unavailable": 503,
    "x-medkit-ros2-action-unavailable": 503,
    "x-medkit-ros2-action-rejected": 400,
    "x-medkit-ros2-type-introspection-failed": 400,
    "x-medkit-ros2-node-unavailable": 503,
    "x-medkit-ros2-parameter-read-only": 403,
}
CLIENT_TIMEOUT = 20.0  # seconds, per socket operation; far above any deadline of the gateway


def problem(status: int, headers: dict[str, str], body: bytes, *,
            allow: Iterable[int] = ()) -> str | None:
    """What breaks the contract in this answer, or None.

    2xx and every 4xx are fine when the body is JSON (errors: a known
    ``error_code`` and a ``message``).  5xx are fine only as documented
    errors: 503 ``vendor-error`` with a known ``vendor_code`` and a
    ``Retry-After``, 502 ``x-medkit-message-undecodable``, 504 ``not-responding``,
    501 ``not-implemented``.  A 500 is
    a problem unless ``allow`` lists it.
    """
    ctype = headers.get("content-type", "")
    if status == 200 and ctype.startswith("text/event-stream"):  # a stream (faults, triggers, subscriptions)
        return None
    if status == 204:  # no content: no body to check (whatever type the framework names)
        return None if not body else f"204 with a body: {body[:80]!r}"
    if not ctype.startswith("application/json"):
        return f"{status} with Content-Type {ctype!r}"
    try:
        doc = json.loads(body)
    except ValueError:
        return f"{status} with a body that is not JSON: {body[:80]!r}"
    if 200 <= status < 300:  # 200, and 201/202/207 of the writes (a lock, a goal, a reset)
        return None if isinstance(doc, dict) else f"{status} with a {type(doc).__name__} body"
    if not isinstance(doc, dict) or doc.get("error_code") not in ERROR_CODES \
            or not isinstance(doc.get("message"), str):
        return f"{status} with an error body outside the contract: {body[:160]!r}"
    if "traceback" in body.decode("utf-8", "replace").lower():
        return f"{status} with a traceback in the body"
    vendor = doc.get("vendor_code")
    if doc["error_code"] == "vendor-error" and VENDOR_CODES.get(vendor) != status:
        return f"{status} vendor-error with vendor_code {vendor!r}"
    if 400 <= status < 500 or status in allow:
        return None
    if status == 503:
        if doc["error_code"] != "vendor-error":
            return f"503 {doc['error_code']} without a vendor code"
        if not headers.get("retry-after", "").isdigit():
            return f"503 {vendor} without a Retry-After header"
        return None
    if status == 502:  # vendor-error with its vendor code, checked above
        return None if doc["error_code"] == "vendor-error" else f"502 {doc['error_code']}"
    if status == 504:
        return None if doc["error_code"] == "not-responding" else f"504 {doc['error_code']}"
    if status == 501:
        return None if doc["error_code"] == "not-implemented" else f"501 {doc['error_code']}"
    return f"{status} {doc['error_code']}: {doc.get('message')!r}"


def error_key(status: int, body: bytes) -> str:
    """``"503 x-medkit-cold-wait-cap-exceeded"``, ``"404 entity-not-found"``, ``"200"``."""
    if status == 200:
        return "200"
    try:
        doc = json.loads(body)
        return f"{status} {doc.get('vendor_code') or doc.get('error_code')}"
    except (ValueError, AttributeError):
        return str(status)


# ---------------------------------------------------------------------------------- HTTP
class Client:
    """One keep-alive HTTP/1.1 connection; every socket operation has a timeout."""

    def __init__(self, port: int, host: str = "127.0.0.1", timeout: float = CLIENT_TIMEOUT):
        self.host, self.port, self.timeout = host, port, timeout
        self.conn: http.client.HTTPConnection | None = None

    def request(self, method: str, path: str, body: bytes | None = None,
                headers: dict[str, str] | None = None) -> tuple[int, dict[str, str], bytes]:
        if self.conn is None:
            self.conn = http.client.HTTPConnection(self.host, self.port, timeout=self.timeout)
        try:
            self.conn.request(method, path, body=body, headers=headers or {})
            resp = self.conn.getresponse()
            data = resp.read()
            hdrs = {k.lower(): v for k, v in resp.getheaders()}
            if resp.will_close:
                self.close()
            return resp.status, hdrs, data
        except BaseException:
            self.close()
            raise

    def get_json(self, path: str) -> tuple[int, Any]:
        status, _, body = self.request("GET", path)
        return status, json.loads(body)

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
            self.conn = None


def raw_exchange(port: int, data: bytes, timeout: float = 10.0) -> tuple[int | None, bytes]:
    """Send ``data`` as is on a fresh connection; ``(status or None, whole answer)``.

    For requests that ``http.client`` refuses to send (NUL bytes, bad request lines).
    """
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
        try:
            s.sendall(data)
            s.shutdown(socket.SHUT_WR)
        except (BrokenPipeError, ConnectionResetError, OSError):
            # the server answered (e.g. 413) and closed before reading everything
            # (ENOTCONN from shutdown when it closed first)
            pass
        chunks = []
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                chunk = s.recv(65536)
            except ConnectionResetError:
                break
            if not chunk:
                break
            chunks.append(chunk)
        answer = b"".join(chunks)
    if answer.startswith(b"HTTP/1."):
        try:
            return int(answer.split(b" ", 2)[1]), answer
        except (IndexError, ValueError):
            pass
    return None, answer


@dataclass(slots=True)
class Req:
    """One request of a load mix: ``kind`` names it in the figures."""

    kind: str
    method: str
    path: str
    body: bytes | None = None
    headers: dict[str, str] | None = None
    allow: tuple[int, ...] = ()


@dataclass(slots=True)
class Answer:
    kind: str
    path: str
    started: float          # monotonic
    elapsed: float          # seconds
    status: int | str       # HTTP status, or the name of the client-side exception
    key: str                # status plus error/vendor code, e.g. "503 x-medkit-cold-wait-cap-exceeded"
    problem: str | None     # what breaks the contract, if anything
    info: Any = None        # what the scenario's ``inspect`` took from the answer

    @property
    def finished(self) -> float:
        return self.started + self.elapsed

    @property
    def timed_out(self) -> bool:
        return self.status in ("TimeoutError", "timeout")


def call(client: Client, req: Req, inspect: Callable[[Req, int, dict, bytes], Any] | None = None) -> Answer:
    started = time.monotonic()
    try:
        status, headers, body = client.request(req.method, req.path, req.body, req.headers)
    except (OSError, http.client.HTTPException) as exc:
        name = type(exc).__name__
        return Answer(req.kind, req.path, started, time.monotonic() - started, name, name, None)
    elapsed = time.monotonic() - started
    info = inspect(req, status, headers, body) if inspect else None
    return Answer(req.kind, req.path, started, elapsed, status, error_key(status, body),
                  problem(status, headers, body, allow=req.allow), info)


class Load:
    """``clients`` threads, each with its own connection, sending ``plan(rng)`` requests.

    Runs until :meth:`stop`, ``duration`` seconds, or ``total`` requests in all.
    """

    def __init__(self, port: int, plan: Callable[[random.Random], Req], clients: int, *,
                 duration: float | None = None, total: int | None = None,
                 inspect: Callable[[Req, int, dict, bytes], Any] | None = None,
                 pause: float = 0.0, seed: int = 1):
        self.port, self.plan, self.clients = port, plan, clients
        self.duration, self.total, self.inspect, self.pause = duration, total, inspect, pause
        self.answers: list[Answer] = []
        self._stop = threading.Event()
        self._sent = 0
        self._lock = threading.Lock()
        self._threads = [threading.Thread(target=self._run, args=(seed + i,), daemon=True,
                                          name=f"load-{i}") for i in range(clients)]
        self.started = 0.0

    def start(self) -> Load:
        self.started = time.monotonic()
        for t in self._threads:
            t.start()
        return self

    def _take(self) -> bool:
        if self._stop.is_set():
            return False
        if self.duration is not None and time.monotonic() - self.started >= self.duration:
            return False
        with self._lock:
            if self.total is not None and self._sent >= self.total:
                return False
            self._sent += 1
        return True

    def _run(self, seed: int) -> None:
        rng = random.Random(seed)
        client = Client(self.port)
        try:
            while self._take():
                self.answers.append(call(client, self.plan(rng), self.inspect))
                if self.pause:
                    time.sleep(self.pause)
        finally:
            client.close()

    def stop(self) -> None:
        self._stop.set()

    def join(self, timeout: float) -> list[Answer]:
        """Wait for every client; fail if one is still running after ``timeout`` (a hang)."""
        deadline = time.monotonic() + timeout
        for t in self._threads:
            t.join(max(0.0, deadline - time.monotonic()))
        hung = [t.name for t in self._threads if t.is_alive()]
        self._stop.set()
        assert not hung, f"load clients still running after {timeout} s: {hung}"
        return self.answers

    def run(self, timeout: float) -> list[Answer]:
        """Start, wait for the duration or the count, return the answers."""
        self.start()
        budget = (self.duration or 0) + timeout
        return self.join(budget)

    def count(self) -> int:
        return len(self.answers)


class HealthProbe:
    """Polls ``GET /api/v1/health`` every ``interval`` s on its own connection, with timings."""

    def __init__(self, port: int, interval: float = 0.1):
        self.port, self.interval = port, interval
        self.samples: list[tuple[float, float, int | str, dict | None]] = []  # started, elapsed, status, body
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name="health-probe")

    def __enter__(self) -> HealthProbe:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def _run(self) -> None:
        client = Client(self.port, timeout=10)
        try:
            while not self._stop.is_set():
                started = time.monotonic()
                try:
                    status, _, body = client.request("GET", "/api/v1/health")
                    doc = json.loads(body) if status == 200 else None
                except (OSError, http.client.HTTPException, ValueError) as exc:
                    status, doc = type(exc).__name__, None
                self.samples.append((started, time.monotonic() - started, status, doc))
                self._stop.wait(self.interval)
        finally:
            client.close()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(15)
        assert not self._thread.is_alive(), "the /health probe hung"

    def latencies(self) -> list[float]:
        return [s[1] for s in self.samples]

    def p99_ms(self) -> float | None:
        return percentile_ms(self.latencies(), 99)

    def worst_ms(self) -> float | None:
        lat = self.latencies()
        return max(lat) * 1000 if lat else None

    def bodies(self) -> list[dict]:
        return [s[3] for s in self.samples if s[3]]

    def max_of(self, section: str, key: str) -> int:
        return max((b[section][key] for b in self.bodies()), default=0)


def percentile_ms(values: list[float], pct: float) -> float | None:
    if not values:
        return None
    ordered = sorted(values)
    index = min(len(ordered) - 1, max(0, int(round(pct / 100 * len(ordered) + 0.5)) - 1))
    return ordered[index] * 1000


# ---------------------------------------------------------------------------------- processes
@dataclass
class GatewayProcs:
    rosworker: psutil.Process | None
    master: psutil.Process | None
    http: list[psutil.Process] = field(default_factory=list)


def gateway_procs(pid: int) -> GatewayProcs:
    """The ROS worker, the gunicorn master and its HTTP workers under supervisor ``pid``."""
    worker = master = None
    http_workers: list[psutil.Process] = []
    try:
        for child in psutil.Process(pid).children():
            cmd = " ".join(child.cmdline())
            if "rosworker" in cmd:
                worker = child
            elif "gunicorn" in cmd:
                master = child
                http_workers = child.children()
    except psutil.Error:
        pass
    return GatewayProcs(worker, master, http_workers)


def rss_mb(proc: psutil.Process | None) -> float | None:
    try:
        return proc.memory_info().rss / 2**20 if proc is not None else None
    except psutil.Error:
        return None


def fds(proc: psutil.Process | None) -> int | None:
    try:
        return proc.num_fds() if proc is not None else None
    except psutil.Error:
        return None


def memory(pid: int) -> dict[str, float | None]:
    """RSS in MB of the ROS worker and of the largest HTTP worker (and their sum)."""
    procs = gateway_procs(pid)
    http_rss = [r for r in (rss_mb(p) for p in procs.http) if r is not None]
    return {"rosworker": rss_mb(procs.rosworker),
            "http_max": max(http_rss) if http_rss else None,
            "http_sum": sum(http_rss) if http_rss else None}


def restarts_in(output: list[str]) -> int:
    """ROS worker restarts the supervisor logged."""
    return sum("restarting ROS worker (attempt" in line for line in output)


# ---------------------------------------------------------------------------------- figures
FIGURES: list[dict[str, Any]] = []


def record(scenario: str, answers: list[Answer] | None = None, *, probe: HealthProbe | None = None,
           restarts: int | None = None, rss_before: dict | None = None, rss_after: dict | None = None,
           requests: int | None = None, statuses: dict[str, int] | None = None,
           worst_ms: float | None = None, note: str = "") -> dict[str, Any]:
    answers = answers or []
    counts = collections.Counter(statuses or {})
    counts.update(a.key for a in answers)
    row = {
        "scenario": scenario,
        "mode": MODE,
        "requests": requests if requests is not None else len(answers),
        "statuses": dict(counts.most_common()),
        "worst_ms": worst_ms if worst_ms is not None
        else (max(a.elapsed for a in answers) * 1000 if answers else None),
        "p99_ms": percentile_ms([a.elapsed for a in answers], 99),
        "health_p99_ms": probe.p99_ms() if probe else None,
        "health_worst_ms": probe.worst_ms() if probe else None,
        "restarts": restarts,
        "rss_before": rss_before,
        "rss_after": rss_after,
        "note": note,
    }
    FIGURES.append(row)
    return row


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.0f}"


def _mb(before: dict | None, after: dict | None, key: str) -> str:
    b, a = (before or {}).get(key), (after or {}).get(key)
    if b is None and a is None:
        return "-"
    fb = "?" if b is None else f"{b:.1f}"
    fa = "?" if a is None else f"{a:.1f}"
    return f"{fb}→{fa}"


def table(rows: list[dict[str, Any]]) -> str:
    headers = ["scenario", "requests", "status counts", "worst ms", "p99 ms", "p99 health ms",
               "restarts", "RSS rosworker MB", "RSS http max MB", "note"]
    lines = []
    for r in rows:
        statuses = ", ".join(f"{k}: {v}" for k, v in r["statuses"].items()) or "-"
        lines.append([r["scenario"], str(r["requests"]), statuses, _ms(r["worst_ms"]), _ms(r["p99_ms"]),
                      _ms(r["health_p99_ms"]), "-" if r["restarts"] is None else str(r["restarts"]),
                      _mb(r["rss_before"], r["rss_after"], "rosworker"),
                      _mb(r["rss_before"], r["rss_after"], "http_max"), r["note"]])
    widths = [max(len(h), *(len(line[i]) for line in lines)) if lines else len(h)
              for i, h in enumerate(headers)]
    # the status column and the note wrap badly in a terminal: cap them, the JSON has it all
    widths[2] = min(widths[2], 70)
    out = [" | ".join(h.ljust(w) for h, w in zip(headers, widths, strict=True)),
           "-+-".join("-" * w for w in widths)]
    for line in lines:
        status_parts = _wrap(line[2], widths[2])
        first = line[:2] + [status_parts[0]] + line[3:]
        out.append(" | ".join(c.ljust(w) for c, w in zip(first, widths, strict=True)))
        for extra in status_parts[1:]:
            blank = [""] * len(headers)
            blank[2] = extra
            out.append(" | ".join(c.ljust(w) for c, w in zip(blank, widths, strict=True)).rstrip())
    return "\n".join(out)


def _wrap(text: str, width: int) -> list[str]:
    parts, line = [], ""
    for item in text.split(", "):
        candidate = item if not line else line + ", " + item
        if len(candidate) > width and line:
            parts.append(line + ",")
            line = item
        else:
            line = candidate
    parts.append(line)
    return parts
