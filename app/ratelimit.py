"""Rate limiting: token buckets per client address and over all clients, shared by every HTTP worker.

Settings (``common/settings.py``): ``rate_limit`` (per client) and
``rate_limit_global`` (all clients together), each ``RATE/BURST``: a bucket
holds at most BURST tokens, gains RATE per second, and each request takes
one.  Both are off by default.  A request is let through only when both its
client's bucket and the global one hold a token; a refused request takes
nothing (so a client over its own limit does not drain the global bucket).
The client is the token's client id when the request carries a good bearer token, else the real
address behind nginx (``app/core/clientaddr.py``; ``app/auth/``'s ``rate_key``).  An event
stream is one request, counted when it opens.  ``/api/v1/health`` and
``/metrics`` are never limited, so monitoring cannot be locked out; nor
are CORS preflights, which a browser sends before the request that counts
(a refused preflight would hide that request's 429 from the page).

Refused: 429 with medkit's error (``error_code`` ``rate-limit-exceeded``,
``parameters`` ``retry_after``, ``limit``, ``reset``, ``scope``) and
``Retry-After``.  Every limited response, let through or not, carries
``X-RateLimit-Limit`` (the bucket's BURST), ``X-RateLimit-Remaining`` (whole
tokens left) and ``X-RateLimit-Reset`` (Unix time at which the bucket is full
again), of whichever bucket is closer to empty.

Shared by all workers without a server (:class:`SharedBuckets`): the buckets
live in one file of the runtime directory (``ratelimit.buckets``, 0600,
removed by the supervisor at start-up) that each worker maps into memory.  A
check takes an ``flock`` on it for the few microseconds of one bucket update
(no I/O in between; the kernel releases it if its holder dies) and gives up
after ``LOCK_WAIT`` and lets the request through rather than wait longer.
Client buckets sit in a fixed table (``SLOTS`` entries, found by a keyed hash
of the address, ``PROBE`` places each): a bucket that has refilled is the
same as no bucket, so its place is taken first; only when all ``PROBE``
places hold draining buckets is the longest-idle one given up (that client
starts with a full bucket again).  Memory stays bounded however many
addresses come.

Why not flask-limiter: its ``limits`` strategies are fixed and moving
windows, not a token bucket with a burst, and its storages shared between
processes all need a server (Redis, Memcached, MongoDB, etcd); the memory
storage is per process, so two workers would allow twice the limit.

Who calls what: :func:`_check` runs before each request, :func:`_headers`
after it, on the request's greenlet.
"""

from __future__ import annotations

import errno
import fcntl
import functools
import hashlib
import logging
import math
import mmap
import os
import struct
import time
from dataclasses import dataclass

from flask import Flask, Response, current_app, request

from common import runfiles, settings
from common.process import PerProcess

from . import auth
from .core import metrics
from .core.errors import ApiError, error_response

log = logging.getLogger("sovd.http.ratelimit")

EXTENSION = "sovd_ratelimit"
EXEMPT_ENDPOINTS = frozenset({"root.health", "metrics.metrics"})
SLOTS = 8192          # client buckets held at once (32 bytes each)
PROBE = 8             # places a client's bucket may take in the table
LOCK_WAIT = 0.05      # seconds a check waits for the lock before it lets the request through
LOCK_RETRY = 0.0002
KEY_CACHE = 4096      # addresses whose bucket key a worker remembers
MAGIC = b"SOVDRL01"
_HEADER = struct.Struct("<8sI4x16sdd")   # magic, slots, salt, global tokens, global last refill
_SLOT = struct.Struct("<16sdd")          # key, tokens, last refill (monotonic; 0 = empty)
_GLOBAL = struct.Struct("<dd")           # the global bucket, at the end of the header
_GLOBAL_AT = _HEADER.size - _GLOBAL.size


@dataclass(frozen=True, slots=True)
class Decision:
    allowed: bool
    scope: str          # the bucket the headers describe: "client" or "global"
    limit: int          # its burst
    remaining: int      # whole tokens left in it
    full_in: float      # seconds until it is full again
    retry_after: int    # when refused: whole seconds until a request would be let through


class _MappedFile:
    """One process's descriptor and map of the bucket file, and its cache of bucket keys."""

    @classmethod
    def open(cls, path: str, size: int, slots: int) -> _MappedFile:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)  # once per process, before the first check
            try:
                if os.fstat(fd).st_size != size or os.pread(fd, len(MAGIC), 0) != MAGIC:
                    os.ftruncate(fd, 0)
                    os.ftruncate(fd, size)
                    os.pwrite(fd, _HEADER.pack(MAGIC, slots, os.urandom(16), 0.0, 0.0), 0)
                mapped = mmap.mmap(fd, size)
            finally:
                fcntl.flock(fd, fcntl.LOCK_UN)
        except BaseException:
            os.close(fd)
            raise
        return cls(fd, mapped)

    def __init__(self, fd: int, mapped: mmap.mmap):
        self.fd = fd
        self.map = mapped
        self.salt = _HEADER.unpack_from(mapped, 0)[2]
        self.key = functools.lru_cache(maxsize=KEY_CACHE)(self._digest)

    def _digest(self, address: str) -> bytes:
        """The bucket key of an address: a hash keyed by the file's random salt (no chosen collisions)."""
        return hashlib.blake2b(address.encode("utf-8", "surrogateescape"), digest_size=16,
                               key=self.salt).digest()

    def close(self) -> None:
        self.map.close()
        os.close(self.fd)


class SharedBuckets:
    """The client and global token buckets in one memory-mapped file (see the module docstring)."""

    def __init__(self, path: str, client: settings.Rate | None, overall: settings.Rate | None,
                 slots: int = SLOTS):
        self.path = path
        self.client = client
        self.overall = overall
        self.slots = slots
        self.size = _HEADER.size + slots * _SLOT.size
        # (a partial, not a bound method: no reference cycle, so the map is freed with self)
        self._file: PerProcess[_MappedFile] = PerProcess(
            functools.partial(_MappedFile.open, path, self.size, slots), _MappedFile.close)
        self._lock_failures = 0
        self._lock_logged = 0.0

    # ---- the file, per process ----------------------------------------------------------------
    def _open(self) -> _MappedFile:
        """This process's map of the file (mapped on first use)."""
        return self._file.get()

    @property
    def _map(self) -> mmap.mmap:
        return self._open().map

    @property
    def _salt(self) -> bytes:
        return self._open().salt

    def close(self) -> None:
        self._file.reset()

    def _lock(self, fd: int) -> bool:
        deadline = time.monotonic() + LOCK_WAIT
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                return True
            except OSError as exc:
                if exc.errno not in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EINTR):
                    raise
            if time.monotonic() >= deadline:
                return False
            time.sleep(LOCK_RETRY)  # a greenlet switch in an HTTP worker

    # ---- one check ------------------------------------------------------------------------------
    def take(self, address: str, spend: bool = True) -> Decision | None:
        """Take one token for a request of ``address`` (``spend=False``: only look whether one is
        there); None when neither bucket is configured."""
        if self.client is None and self.overall is None:
            return None
        file = self._open()
        key = file.key(address) if self.client is not None else b""
        if not self._lock(file.fd):
            self._lock_failed()
            return None
        try:
            return self._take(file.map, key, time.monotonic(), spend)
        finally:
            fcntl.flock(file.fd, fcntl.LOCK_UN)

    def _take(self, mm: mmap.mmap, key: bytes, now: float, spend: bool = True) -> Decision:
        overall, client = self.overall, self.client
        g_tokens = c_tokens = None
        if overall is not None:
            g_tokens = _refill(overall, *_GLOBAL.unpack_from(mm, _GLOBAL_AT), now)
        if client is not None:
            offset, c_tokens = self._slot(mm, key, now)
        allowed = (g_tokens is None or g_tokens >= 1.0) and (c_tokens is None or c_tokens >= 1.0)
        if allowed and spend:
            g_tokens = None if g_tokens is None else g_tokens - 1.0
            c_tokens = None if c_tokens is None else c_tokens - 1.0
        if g_tokens is not None and spend:
            _GLOBAL.pack_into(mm, _GLOBAL_AT, g_tokens, now)
        if c_tokens is not None and spend:
            _SLOT.pack_into(mm, offset, key, c_tokens, now)
        # Describe the bucket that refused (the longer wait if both did), else the emptier one.
        if c_tokens is None:
            use_global = True
        elif g_tokens is None:
            use_global = False
        elif allowed:
            use_global = g_tokens < c_tokens
        elif g_tokens < 1.0 and c_tokens < 1.0:
            use_global = (1.0 - g_tokens) / overall.rate > (1.0 - c_tokens) / client.rate
        else:
            use_global = g_tokens < 1.0
        scope, rate, tokens = ("global", overall, g_tokens) if use_global else ("client", client, c_tokens)
        retry = 0 if allowed else max(1, math.ceil((1.0 - tokens) / rate.rate))
        return Decision(allowed, scope, rate.burst, max(0, int(tokens)), (rate.burst - tokens) / rate.rate, retry)

    def _slot(self, mm: mmap.mmap, key: bytes, now: float) -> tuple[int, float]:
        """The offset of ``key``'s bucket (found, or a place for it) and its tokens now."""
        rate = self.client
        start = int.from_bytes(key[:8], "little") % self.slots
        free = None          # an empty place, or one whose bucket has refilled: as good as empty
        oldest = None        # else the longest idle bucket
        oldest_last = math.inf
        for i in range(PROBE):
            offset = _HEADER.size + ((start + i) % self.slots) * _SLOT.size
            slot_key, tokens, last = _SLOT.unpack_from(mm, offset)
            if last and slot_key == key:
                return offset, _refill(rate, tokens, last, now)
            if free is None and (not last or _refill(rate, tokens, last, now) >= rate.burst):
                free = offset
            elif last < oldest_last:
                oldest, oldest_last = offset, last
        return (free if free is not None else oldest), float(rate.burst)

    def _lock_failed(self) -> None:
        self._lock_failures += 1
        now = time.monotonic()
        if now - self._lock_logged >= 10.0:
            self._lock_logged = now
            log.warning("rate limiter: the bucket file stayed locked for %g s; let %d request(s) through "
                        "unchecked", LOCK_WAIT, self._lock_failures)


def _refill(rate: settings.Rate, tokens: float, last: float, now: float) -> float:
    if not last:
        return float(rate.burst)
    return rate.refill(tokens, now - last)


# ---- Flask ------------------------------------------------------------------------------------------
DECISION = "sovd.ratelimit"  # in the request's environ: the decision its headers describe


def _check() -> Response | None:
    req = request._get_current_object()
    if req.endpoint in EXEMPT_ENDPOINTS or _preflight(req):
        return None
    decision = current_app.extensions[EXTENSION].take(auth.rate_key(req))
    if decision is None:
        return None
    req.environ[DECISION] = decision
    if decision.allowed:
        return None
    metrics.rate_limited(decision.scope)
    reset = _reset(decision)
    return error_response(ApiError(
        429, "rate-limit-exceeded",
        f"Too many requests. Please retry after {decision.retry_after} seconds.",
        {"retry_after": decision.retry_after, "limit": decision.limit, "reset": reset,
         "scope": decision.scope},
        retry_after=decision.retry_after))


def _preflight(req) -> bool:
    """A CORS preflight: not counted (refusing it would hide the 429 of the real request from the page)."""
    return req.method == "OPTIONS" and "Access-Control-Request-Method" in req.headers


def _reset(decision: Decision) -> int:
    return math.ceil(time.time() + decision.full_in)


def _headers(response: Response) -> Response:
    decision = request.environ.get(DECISION)
    if decision is not None:
        response.headers.extend((("X-RateLimit-Limit", str(decision.limit)),
                                 ("X-RateLimit-Remaining", str(decision.remaining)),
                                 ("X-RateLimit-Reset", str(_reset(decision)))))
    return response


def init_app(app: Flask) -> None:
    """Register the check (after ``clientaddr.init_app``) when a limit is configured."""
    cfg = app.config["SOVD"]
    client = settings.parse_rate(cfg.rate_limit, "rate_limit")
    overall = settings.parse_rate(cfg.rate_limit_global, "rate_limit_global")
    if client is None and overall is None:
        return
    app.extensions[EXTENSION] = SharedBuckets(os.path.join(cfg.runtime_dir, runfiles.RATELIMIT_FILE), client, overall)
    app.before_request(_check)
    app.after_request(_headers)
