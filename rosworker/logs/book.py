"""``/rosout`` as SOVD logs: one subscription, a ring buffer per node, the logs' configuration.

One subscription to ``/rosout`` (``rcl_interfaces/msg/Log``) with the QoS that
rcl's rosout publishers offer (reliable, transient-local, keep-last 1000: a
node's lines from before the gateway started, up to rcl's depth, are heard
too).  Like the pool's, it is never spun: the ROS thread takes what came
when lines come (``core/batched.py``: woken by the first, then at most every
``DRAIN_EVERY`` s while they keep coming), at most ``TAKES_PER_ROUND`` messages a
round, so a storm of log lines costs bounded CPU (past that rate DDS keeps the
newest ``ROSOUT_DEPTH`` lines and drops the oldest; the rounds that hit the
budget are counted in ``logs_saturated_rounds``).  A message is taken as CDR and
parsed here (``parse_log``: about six times cheaper than rclpy's conversion).

Memory is bounded three ways: ``log_buffer_size`` entries per node (the
oldest goes first, as in medkit), ``log_max_bytes`` in all (the oldest
anywhere goes first) and ``log_max_nodes`` nodes (lines of a new node past it
are dropped, counted, and its name logged once).  A message is cut at
``MAX_TEXT`` characters.  Lines lost before they reached us (a gap in a
publisher's sequence numbers, when the middleware reports them) are counted in
``logs_lost``.

The configuration (``severity_filter``, ``max_entries``) of each entity lives
here, so every HTTP worker sees the same; at most ``MAX_CONFIGS`` entities
have one (the oldest set goes first).  Nothing is written to disk: logs are
memory only, as in medkit.

The queries' rules are medkit's (``log_manager.cpp``): a node matches by its
logger name in slash or dot form; the stricter of the query's severity and
the entity's ``severity_filter`` applies; ``context`` is a substring of the
logger name; entries come oldest first, the newest ``max_entries``.  Rows go
to the HTTP side as lists (``ROW``); it formats them (``app/logs/routes.py``).
"""

from __future__ import annotations

import collections
import heapq
import itertools
import logging
import struct
from collections.abc import Callable, Iterable
from typing import Any

from ipc.errors import IpcError

from ..core import args as check
from ..core.batched import Batched
from ..core.executor import RosExecutor
from ..core.stats import Stats
from ..core.task import Task

log = logging.getLogger("sovd.rosworker.logs")

TOPIC = "/rosout"
TYPE = "rcl_interfaces/msg/Log"
ROSOUT_DEPTH = 1000       # rcl's rosout QoS: keep-last 1000, reliable, transient-local, lifespan 10 s
ROSOUT_LIFESPAN_S = 10
DRAIN_EVERY = 0.05        # seconds between takes from /rosout
TAKES_PER_ROUND = 500     # messages taken at most per round: 10,000 lines/s
MAX_TEXT = 8192           # characters of a message kept (a longer one is cut, with a marker)
MAX_NAME = 1024           # characters of a logger, file or function name kept
ENTRY_OVERHEAD = 120      # bytes counted per entry besides its strings
MAX_CONFIGS = 10000       # entities with a configuration of their own
DROPPED_NAMES_LOGGED = 100  # nodes whose dropped lines are logged (once each)
SEVERITIES = {"debug": 10, "info": 20, "warning": 30, "error": 40, "fatal": 50}
LEVELS = {level: name for name, level in SEVERITIES.items()}
DEFAULT_CONFIG = {"severity_filter": "debug", "max_entries": 100}   # medkit's LogConfig{}
MAX_ENTRIES = 10000
# One entry on the wire: [id, sec, nanosec, level, name, msg, file, function, line].
ROW = ("id", "sec", "nanosec", "level", "name", "msg", "file", "function", "line")

_HEAD = struct.Struct("<iIB")
_U32 = struct.Struct("<I")


def parse_log(raw: bytes) -> tuple[int, int, int, str, str, str, str, int] | None:
    """A little-endian CDR ``rcl_interfaces/msg/Log`` → (sec, nanosec, level, name, msg, file, function, line).

    None when it is not little-endian CDR (the caller converts it with rclpy); raises
    ValueError or struct.error on a truncated message.
    """
    if len(raw) < 4 or raw[1] != 1:  # encapsulation: 0x0001 is CDR little-endian
        return None
    sec, nanosec, level = _HEAD.unpack_from(raw, 4)
    offset = 13
    texts = []
    for limit in (MAX_NAME, MAX_TEXT, MAX_NAME, MAX_NAME):
        offset = (offset + 3) & ~3  # alignment counts from after the 4-byte header: 4 + 4k
        (size,) = _U32.unpack_from(raw, offset)
        offset += 4
        if size == 0 or offset + size > len(raw):
            raise ValueError("string past the end of the message")
        texts.append(_cut(raw[offset:offset + size - 1].decode("utf-8", "replace"), limit))
        offset += size
    offset = (offset + 3) & ~3
    (line,) = _U32.unpack_from(raw, offset)
    return sec, nanosec, level, texts[0], texts[1], texts[2], texts[3], line


def _cut(text: str, limit: int) -> str:
    return text if len(text) <= limit else text[:limit] + f"… [cut: {len(text)} characters]"


class Entry:
    __slots__ = ("id", "sec", "nanosec", "level", "name", "msg", "file", "function", "line", "nbytes", "live")

    def __init__(self, id_: int, sec: int, nanosec: int, level: int, name: str, msg: str, file: str,
                 function: str, line: int):
        self.id, self.sec, self.nanosec, self.level = id_, sec, nanosec, level
        self.name, self.msg, self.file, self.function, self.line = name, msg, file, function, line
        self.nbytes = ENTRY_OVERHEAD + len(msg) + len(file) + len(function)
        self.live = True

    def row(self) -> list[Any]:
        return [self.id, self.sec, self.nanosec, self.level, self.name, self.msg, self.file, self.function,
                self.line]


def names_of(fqn: str) -> tuple[str, str]:
    """A node's FQN (``/demo/battery``) as a logger name in slash and dot form (medkit's match)."""
    norm = fqn[1:] if fqn.startswith("/") else fqn
    return norm, norm.replace("/", ".")


class LogBook:
    """The ring buffers, their counters and the entities' configurations (ROS thread only)."""

    def __init__(self, node: Any, executor: RosExecutor, stats: Stats, *, buffer_size: int, max_bytes: int,
                 max_nodes: int):
        self.node = node
        self.executor = executor
        self.stats = stats
        self.buffer_size = buffer_size
        self.max_bytes = max_bytes
        self.max_nodes = max_nodes
        self.buffers: dict[str, collections.deque[Entry]] = {}
        self._order: collections.deque[Entry] = collections.deque()  # every entry, oldest first
        self._live = 0
        self.nbytes = 0
        self._ids = itertools.count(1)
        self._sequence: dict[str, int] = {}   # logger name -> last publication sequence number
        self._dropped_names: set[str] = set()
        self.configs: dict[str, dict[str, Any]] = {}
        self.sub = None
        self._cls = None
        # logs as an observable collection (triggers; core/notifier.py): told of every line while watched
        from .observable import LogObservable

        self.observable = LogObservable(stats)
        stats.logs_buffer_size = buffer_size
        stats.logs_max_bytes = max_bytes
        stats.logs_max_nodes = max_nodes
        self.handlers: dict[str, Callable[[Task], None]] = {
            "logs": self.query_cmd, "log_config_get": self.config_get_cmd, "log_config_set": self.config_set_cmd,
        }

    # ---- the subscription --------------------------------------------------------------
    def start(self) -> None:
        """Subscribe to /rosout; drain it when lines come, at most every ``DRAIN_EVERY`` s (ROS thread,
        before the loop runs)."""
        from rcl_interfaces.msg import Log
        from rclpy.duration import Duration
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        profile = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=ROSOUT_DEPTH,
                             reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             lifespan=Duration(seconds=ROSOUT_LIFESPAN_S))
        self._cls = Log
        self.sub = self.node.create_subscription(Log, TOPIC, _never_called, profile)
        Batched(self.executor, "/rosout", lambda: self.sub, self.drain, DRAIN_EVERY)

    def drain(self, budget: int = TAKES_PER_ROUND) -> int:
        """Take up to ``budget`` lines from /rosout into the buffers; how many were taken."""
        take = self.sub.handle.take_message
        for taken in range(budget):
            message = take(self._cls, True)
            if message is None:
                return taken
            raw, info = message
            try:
                fields = parse_log(raw)
                if fields is None:
                    fields = self._convert(raw)
            except (ValueError, struct.error):
                self.stats.logs_undecodable += 1
                continue
            self._note_sequence(fields[3], info)
            self.add(*fields)
        self.stats.logs_saturated_rounds += 1
        return budget

    def _convert(self, raw: bytes) -> tuple[int, int, int, str, str, str, str, int]:
        from rclpy.serialization import deserialize_message

        try:
            m = deserialize_message(raw, self._cls)
        except Exception as exc:  # rclpy raises several types for bad CDR
            raise ValueError(str(exc)) from None
        return (m.stamp.sec, m.stamp.nanosec, m.level, _cut(m.name, MAX_NAME), _cut(m.msg, MAX_TEXT),
                _cut(m.file, MAX_NAME), _cut(m.function, MAX_NAME), m.line)

    def _note_sequence(self, name: str, info: dict) -> None:
        """Count lines lost on the way (a gap in the publisher's sequence numbers)."""
        seq = info.get("publication_sequence_number") if isinstance(info, dict) else None
        if not isinstance(seq, int) or seq <= 0 or seq >= 2**63:
            return  # the middleware does not report it
        last = self._sequence.get(name)
        if last is not None and seq > last + 1:
            self.stats.logs_lost += seq - last - 1
        if last is not None or len(self._sequence) < self.max_nodes:
            self._sequence[name] = seq  # a smaller number: a restarted node (or two of one name)

    # ---- the buffers -------------------------------------------------------------------
    def add(self, sec: int, nanosec: int, level: int, name: str, msg: str, file: str, function: str,
            line: int) -> None:
        self.stats.logs_received += 1
        buf = self.buffers.get(name)
        if buf is None:
            if len(self.buffers) >= self.max_nodes:
                self.stats.logs_dropped += 1
                if name not in self._dropped_names and len(self._dropped_names) < DROPPED_NAMES_LOGGED:
                    self._dropped_names.add(name)
                    log.warning("dropping log lines of node %r: %d nodes are buffered already (log_max_nodes)",
                                name[:200], self.max_nodes)
                return
            buf = self.buffers[name] = collections.deque()
            self.stats.logs_nodes = len(self.buffers)
        entry = Entry(next(self._ids), sec, nanosec, level, name, msg, file, function, line)
        buf.append(entry)
        self._order.append(entry)
        self._live += 1
        self.nbytes += entry.nbytes
        if len(buf) > self.buffer_size:
            self._retire(buf.popleft())
        while self.nbytes > self.max_bytes and self._live > 1:
            self._evict_oldest()
        if len(self._order) > 2 * self._live + 64:
            self._order = collections.deque(e for e in self._order if e.live)
        self.stats.logs_buffered = self._live
        self.stats.logs_bytes = self.nbytes
        if self.observable.observers:  # logs triggers: evaluated on the line, nothing when none watches
            self.executor.guarded("the logs triggers", self.observable.on_line, entry)

    def _retire(self, entry: Entry) -> None:
        entry.live = False
        self._live -= 1
        self.nbytes -= entry.nbytes
        self.stats.logs_evicted += 1

    def _evict_oldest(self) -> None:
        while self._order:
            entry = self._order.popleft()
            if not entry.live:
                continue
            buf = self.buffers[entry.name]
            buf.popleft()  # the oldest of its node too
            self._retire(entry)
            if not buf:
                del self.buffers[entry.name]
                self._sequence.pop(entry.name, None)
                self.stats.logs_nodes = len(self.buffers)
            return

    def query(self, loggers: Iterable[str], min_level: int, context: str, limit: int) -> list[list[Any]]:
        """The newest ``limit`` entries of these loggers at ``min_level`` or above, oldest first."""
        # Each matching node's entries, newest first and filtered lazily, merged by id until ``limit``
        # match: a dense query reads about ``limit`` entries, a sparse one each entry once (a buffer
        # holds one logger, so ``context`` is checked once per node).  2,000 full buffers (400,000 entries):
        # 10 ms for 100 lines, about 1 s at worst (10,000 lines of a sparse severity) on the 2-core VM.
        runs = []
        for name in dict.fromkeys(loggers):
            buf = self.buffers.get(name)
            if buf is None or (context and context not in name):
                continue
            runs.append(reversed(buf) if min_level <= 10 else (e for e in reversed(buf) if e.level >= min_level))
        newest = heapq.merge(*runs, key=_newest_first) if len(runs) > 1 else (runs[0] if runs else ())
        picked = list(itertools.islice(newest, limit))
        return [e.row() for e in reversed(picked)]

    # ---- the commands (the HTTP side has checked what a client sent; these guard the wire) ----
    def config(self, entity_id: str) -> dict[str, Any]:
        return dict(self.configs.get(entity_id) or DEFAULT_CONFIG)

    def query_cmd(self, task: Task) -> None:
        args = task.args
        entity_id = check.string(args, "entity_id", limit=256)
        fqns = check.strings(args, "nodes", 100000, "a list of node names")
        severity = args.get("severity") or ""
        if severity and severity not in SEVERITIES:
            raise IpcError("bad-request", "severity: expected one of " + ", ".join(SEVERITIES))
        context = args.get("context") or ""
        if not isinstance(context, str) or len(context) > 256:
            raise IpcError("bad-request", "context: expected a string of at most 256 characters")
        cfg = self.config(entity_id)
        min_level = max(SEVERITIES[cfg["severity_filter"]], SEVERITIES.get(severity, 0))
        loggers = [name for fqn in fqns for name in names_of(fqn)]
        task.reply({"rows": self.query(loggers, min_level, context, cfg["max_entries"])})

    def config_get_cmd(self, task: Task) -> None:
        task.reply(self.config(check.string(task.args, "entity_id", limit=256)))

    def config_set_cmd(self, task: Task) -> None:
        entity_id = check.string(task.args, "entity_id", limit=256)
        cfg = self.config(entity_id)
        severity = task.args.get("severity_filter")
        if severity is not None:
            if severity not in SEVERITIES:
                raise IpcError("bad-request", "severity_filter: expected one of " + ", ".join(SEVERITIES))
            cfg["severity_filter"] = severity
        entries = task.args.get("max_entries")
        if entries is not None:
            cfg["max_entries"] = check.integer(task.args, "max_entries", 1, MAX_ENTRIES)
        self.configs.pop(entity_id, None)
        if len(self.configs) >= MAX_CONFIGS:
            self.configs.pop(next(iter(self.configs)))
        self.configs[entity_id] = cfg
        task.reply(dict(cfg))

    def shutdown(self) -> None:
        if self.sub is not None:
            self.node.destroy_subscription(self.sub)
            self.sub = None


def _newest_first(entry: Entry) -> int:
    return -entry.id


def _never_called(_msg) -> None:  # pragma: no cover - the subscription is never spun
    pass
