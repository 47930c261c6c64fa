"""Recordings on disk: the writer thread, the MCAP files, and the index rebuilt from them.

A closed recording (``recorder.Recording``) is handed to one writer thread (never the
ROS thread, which only queues it: at most ``QUEUE`` wait; past that a recording is
refused and counted).  The writer is pure Python work under the GIL: it hands the GIL
over every ``YIELD_EVERY`` messages and merges the topics' messages in Python steps
rather than sorting them in one C call, so a warm sample on the ROS thread waits for
it at most a few messages' worth; the thread runs at nice ``NICE`` (Linux schedules
threads one by one), so on a busy machine the ROS thread and the HTTP workers come first.  The thread writes it as MCAP with the ROS 2 profile, with the
``mcap`` package: ``ros2msg`` schemas carrying each type's complete message definition
(``msgdefs.py``, as rosbag2 writes them), ``cdr`` message encoding, zstd-compressed
chunks, the messages in receive-time order with their receive time as ``log_time`` and
their source time as ``publish_time``.  Each schema is checked once per type with
``mcap-ros2-support``'s decoder on the channel's first message: a definition that does
not decode its own messages is logged and counted (``rosbag_definition_errors``).

Files: ``<storage>/<recording id>.mcap`` (the id is medkit's, ``fault_<CODE>_<ms>``),
written to ``.<id>.mcap.tmp`` (mode 0600), fsynced, renamed, and the directory fsynced.
The recording's facts (its faults and their sources, times, topics) travel inside the
file as a metadata record (``META_NAME``), so the index is rebuilt from the directory at
start (:meth:`RecordingStore.load`): a recording survives a ROS worker SIGKILL and a
reboot, and a half-written file (a ``.tmp`` left by a SIGKILL) is never listed; it is
removed at start.

Caps (applied after each write and at start, files deleted by this thread):
``fault_rosbag_max_bags_per_fault`` recordings per fault, newest first (a recording that
no fault keeps any more is deleted; one of a burst stays while one of its faults keeps
it, medkit's rule), then ``fault_rosbag_max_total_mb`` on disk and ``MAX_RECORDINGS``,
the oldest recordings deleted first.  A failed write (disk full, an unwritable
directory) is logged and counted (``rosbag_write_errors``) and leaves no file behind;
nothing else is affected.

The index is read by the ROS thread's commands under a lock held only to copy it.
"""

from __future__ import annotations

import errno
import heapq
import json
import logging
import operator
import os
import queue
import threading
import time
from collections import Counter
from typing import Any

from common.process import package_version, remove

from . import msgdefs

log = logging.getLogger("sovd.rosworker.bulk_data")

SUFFIX = ".mcap"
TMP_SUFFIX = ".mcap.tmp"
META_NAME = "sovd_recording"
FORMAT = "mcap"
QUEUE = 2                 # closed recordings waiting for the writer, at most
MAX_RECORDINGS = 1000     # recordings kept, at most (the oldest go first)
CHUNK_SIZE = 1 << 20      # bytes of messages per compressed chunk
YIELD_EVERY = 8           # messages written between two hand-overs of the GIL to the ROS thread
NICE = 10                 # the writer thread's nice value (Linux schedules threads one by one)
ERROR_LOG_EVERY = 60.0    # seconds between two logged write failures of the same kind


class RecordingStore:
    """The recordings directory: its index, the writer thread, the caps."""

    def __init__(self, directory: str, stats, *, max_total_bytes: int, max_per_fault: int):
        self.directory = directory
        self.stats = stats
        self.max_total_bytes = max_total_bytes
        self.max_per_fault = max_per_fault  # 0: no cap
        self._lock = threading.Lock()
        self._index: dict[str, dict[str, Any]] = {}
        self._queue: queue.Queue = queue.Queue(QUEUE)
        self._thread: threading.Thread | None = None
        self._checked: set[str] = set()    # types whose definition was checked against a message
        self._logged: dict[str, float] = {}
        self.pause_s = 0.0                 # test only (debug_commands): a pause in the middle of a write
        stats.rosbag_disk_cap_mb = max_total_bytes // 2**20

    # ---- start and stop ----------------------------------------------------------------------------
    def load(self) -> None:
        """Rebuild the index from the directory: remove what a killed writer left, read each file's facts."""
        try:
            os.makedirs(self.directory, mode=0o700, exist_ok=True)
            names = os.listdir(self.directory)
        except OSError as exc:
            self._failed("the recordings directory", exc)
            return
        index: dict[str, dict[str, Any]] = {}
        for name in names:
            path = os.path.join(self.directory, name)
            if name.startswith(".") and name.endswith(TMP_SUFFIX):
                log.info("removing %s: a recording whose write did not finish (the ROS worker stopped)", path)
                _unlink(path)
                continue
            if not name.endswith(SUFFIX) or name.startswith("."):
                continue
            meta = read_meta(path)
            if meta is None:
                log.warning("%s is not a complete recording of this gateway: not listed", path)
                continue
            index[meta["id"]] = meta
        with self._lock:
            self._index = index
        self._enforce()
        log.info("%d fault recordings in %s", len(index), self.directory)

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="rosbag-writer", daemon=True)
        self._thread.start()

    def submit(self, recording) -> bool:
        """Queue a closed recording for the writer thread (any thread); False when ``QUEUE`` already wait."""
        try:
            self._queue.put_nowait(recording)
        except queue.Full:
            return False
        self.stats.rosbag_writes_pending = self._queue.qsize()
        return True

    def close(self, timeout: float) -> None:
        """Let the writer finish what is queued, within ``timeout`` seconds (shutdown)."""
        if self._thread is None:
            return
        deadline = time.monotonic() + timeout
        try:
            self._queue.put(None, timeout=timeout)
        except queue.Full:
            pass
        self._thread.join(max(0.0, deadline - time.monotonic()))
        if self._thread.is_alive():
            log.warning("the recordings writer did not finish within %g s; a recording being written is "
                        "lost (its temporary file is removed at the next start)", timeout)

    def _run(self) -> None:
        try:  # Linux: this thread only; the ROS thread and the HTTP workers come first for the cores
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), NICE)
        except (AttributeError, OSError):
            pass
        while True:
            recording = self._queue.get()
            if recording is None:
                return
            try:
                self.write(recording)
            except Exception:  # never lose the thread: the next recording is written all the same
                self.stats.rosbag_write_errors += 1
                log.exception("writing recording %s failed", recording.id)
            self.stats.rosbag_writes_pending = self._queue.qsize()

    # ---- writing (the writer thread) ---------------------------------------------------------------
    def write(self, recording) -> dict[str, Any] | None:
        """Write ``recording`` as an MCAP file and list it; None when it could not be written."""
        recording_id = self._free_id(recording.id)
        final = os.path.join(self.directory, recording_id + SUFFIX)
        tmp = os.path.join(self.directory, "." + recording_id + TMP_SUFFIX)
        items = merged(recording.items)
        topics = sorted({channel for _, _, channel, _ in items})
        started = min(recording.created_ns, items[0][0]) if items else recording.created_ns
        meta = {
            "id": recording_id, "format": FORMAT, "all_codes": list(recording.codes),
            "sources": {code: list(s) for code, s in recording.sources.items()},
            "created_ns": recording.created_ns, "started_ns": started, "ended_ns": recording.ended_ns,
            "duration_sec": round(max(0.0, (recording.ended_ns - started) / 1e9), 3),
            "topics": [{"topic": t, "type": ty} for t, ty in topics], "messages": len(items),
        }
        started = time.monotonic()
        try:
            os.makedirs(self.directory, mode=0o700, exist_ok=True)
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600)
        except OSError as exc:
            self._failed(f"recording {recording_id}", exc)
            return None
        try:
            with os.fdopen(fd, "wb") as fh:
                self._write_mcap(fh, items, topics, meta)
                fh.flush()
                os.fsync(fh.fileno())
            os.rename(tmp, final)
            _fsync_dir(self.directory)
        except Exception as exc:
            _unlink(tmp)
            self._failed(f"recording {recording_id}", exc)
            return None
        meta.update(path=final, size=os.stat(final).st_size)
        with self._lock:
            self._index[recording_id] = meta
        self.stats.rosbag_recordings_written += 1
        log.info("recorded faults %s in %s: %d messages of %d topics, %.1f s, %d bytes, written in %.2f s",
                 ", ".join(recording.codes), final, len(items), len(topics), meta["duration_sec"], meta["size"],
                 time.monotonic() - started)
        self._enforce()
        return meta

    def _write_mcap(self, fh, items: list, topics: list[tuple[str, str]], meta: dict[str, Any]) -> None:
        from mcap.writer import LIBRARY_IDENTIFIER as MCAP_LIBRARY
        from mcap.writer import CompressionType, Writer

        writer = Writer(fh, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library=f"sovd-gateway/{package_version()} {MCAP_LIBRARY}")
        schemas: dict[str, int] = {}
        channels: dict[tuple[str, str], int] = {}
        for topic, type_name in topics:
            if type_name not in schemas:
                encoding, text = self._definition(type_name)
                schemas[type_name] = writer.register_schema(name=type_name, encoding=encoding, data=text.encode())
            channels[(topic, type_name)] = writer.register_channel(topic=topic, message_encoding="cdr",
                                                                   schema_id=schemas[type_name])
        first: dict[tuple[str, str], bytes] = {}
        pause_after = len(items) // 2 if self.pause_s else -1
        for sequence, (received, published, channel, raw) in enumerate(items):
            writer.add_message(channel_id=channels[channel], log_time=received, publish_time=published,
                               sequence=sequence & 0xFFFFFFFF, data=raw)
            first.setdefault(channel, raw)
            if not sequence % YIELD_EVERY:
                time.sleep(0)  # the GIL to the ROS thread now, not at the interpreter's next switch
            if sequence == pause_after:
                fh.flush()
                time.sleep(self.pause_s)
        writer.add_metadata(META_NAME, {key: json.dumps(value) for key, value in meta.items()})
        writer.finish()
        for (_, type_name), raw in first.items():
            self._check_definition(type_name, raw)

    def _definition(self, type_name: str) -> tuple[str, str]:
        try:
            return msgdefs.definition(type_name)
        except (LookupError, ValueError, OSError) as exc:
            if type_name not in self._checked:
                self._checked.add(type_name)
                self.stats.rosbag_definition_errors += 1
                log.warning("no message definition for %s (%s): its channel has an empty schema (played back "
                            "by ros2 bag, not decodable by tools that need the definition)", type_name, exc)
            return "ros2msg", ""

    def _check_definition(self, type_name: str, raw: bytes) -> None:
        """Decode one message with the schema written (``mcap-ros2-support``), once per type."""
        if type_name in self._checked:
            return
        self._checked.add(type_name)
        from mcap.records import Schema
        from mcap_ros2.decoder import DecoderFactory

        encoding, text = msgdefs.definition(type_name)
        try:
            decoder = DecoderFactory().decoder_for("cdr", Schema(id=1, name=type_name, encoding=encoding,
                                                                 data=text.encode()))
            if decoder is None:
                raise ValueError(f"no decoder for the {encoding} encoding")
            decoder(raw)
        except Exception as exc:
            self.stats.rosbag_definition_errors += 1
            log.warning("the message definition written for %s does not decode its messages (%s: %s): tools "
                        "that decode from the file (Foxglove) may not show that topic", type_name,
                        type(exc).__name__, str(exc)[:200])

    def _free_id(self, recording_id: str) -> str:
        with self._lock:
            taken = set(self._index)
        candidate, n = recording_id, 1
        while candidate in taken or os.path.exists(os.path.join(self.directory, candidate + SUFFIX)):
            candidate = f"{recording_id}_{n}"
            n += 1
        return candidate

    def _failed(self, what: str, exc: Exception) -> None:
        self.stats.rosbag_write_errors += 1
        kind = errno.errorcode.get(getattr(exc, "errno", None) or 0, type(exc).__name__)
        now = time.monotonic()
        if now - self._logged.get(kind, -ERROR_LOG_EVERY) >= ERROR_LOG_EVERY:
            self._logged[kind] = now
            hint = {"ENOSPC": " (the disk is full)", "EACCES": " (the directory is not writable)",
                    "EROFS": " (the file system is read-only)"}.get(kind, "")
            log.error("%s in %s could not be written%s: %s (further failures of this kind are counted, logged "
                      "at most every %g s)", what, self.directory, hint, exc, ERROR_LOG_EVERY)

    # ---- the caps -------------------------------------------------------------------------------------
    def _enforce(self) -> None:
        """Per-fault cap (newest first), then the disk cap and MAX_RECORDINGS (oldest first)."""
        with self._lock:
            newest_first = sorted(self._index.values(), key=lambda m: m["created_ns"], reverse=True)
            kept: Counter[str] = Counter()
            doomed = []
            for meta in newest_first:
                codes = []
                for code in meta["all_codes"]:
                    if not self.max_per_fault or kept[code] < self.max_per_fault:
                        codes.append(code)
                        kept[code] += 1
                meta["fault_codes"] = codes
                if not codes:
                    doomed.append(meta)
            alive = [m for m in newest_first if m["fault_codes"]]
            total = sum(m["size"] for m in alive)
            while alive and (total > self.max_total_bytes or len(alive) > MAX_RECORDINGS):
                oldest = alive.pop()
                total -= oldest["size"]
                doomed.append(oldest)
            for meta in doomed:
                self._index.pop(meta["id"], None)
            self.stats.rosbag_recordings = len(self._index)
            self.stats.rosbag_disk_bytes = total
        for meta in doomed:
            log.info("deleting recording %s (%s)", meta["id"], "kept by no fault: max_bags_per_fault"
                     if not meta["fault_codes"] else "fault_rosbag_max_total_mb")
            _unlink(meta["path"])
            self.stats.rosbag_evicted += 1

    # ---- reading (any thread) --------------------------------------------------------------------------
    def listing(self) -> list[dict[str, Any]]:
        """Every recording, oldest first, as the commands answer it."""
        with self._lock:
            metas = sorted(self._index.values(), key=lambda m: m["created_ns"])
            return [public(m) for m in metas]

    def get(self, recording_id: str) -> dict[str, Any] | None:
        with self._lock:
            meta = self._index.get(recording_id)
            return public(meta) if meta is not None else None

    def of_fault(self, code: str) -> list[dict[str, Any]]:
        """The recordings that keep fault ``code``, newest first."""
        with self._lock:
            metas = [m for m in self._index.values() if code in m["fault_codes"]]
            return [public(m) for m in sorted(metas, key=lambda m: m["created_ns"], reverse=True)]


def merged(items: list) -> list:
    """The messages in receive-time order.  Each topic's are in order already (taken in turn from its
    queue), so they are merged, in Python steps the interpreter can switch between: one C-level sort
    of a large recording would hold the GIL, and so the ROS thread, for its whole length."""
    by_channel: dict[tuple[str, str], list] = {}
    for n, item in enumerate(items):
        by_channel.setdefault(item[2], []).append(item)
        if not n % (YIELD_EVERY * 16):
            time.sleep(0)
    return list(heapq.merge(*by_channel.values(), key=operator.itemgetter(0)))


def public(meta: dict[str, Any]) -> dict[str, Any]:
    """A recording as the ``bulk_*`` commands and ``fault_get`` answer it (``ipc/PROTOCOL.md``)."""
    return {k: meta[k] for k in ("id", "format", "fault_codes", "sources", "created_ns", "started_ns",
                                 "ended_ns", "duration_sec", "topics", "messages", "path", "size")}


def read_meta(path: str) -> dict[str, Any] | None:
    """A finished recording's facts, from its metadata record (None: not a complete recording of ours)."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as fh:
            reader = make_reader(fh)
            record = next((m for m in reader.iter_metadata() if m.name == META_NAME), None)
            if record is None:
                return None
            meta = {key: json.loads(value) for key, value in record.metadata.items()}
            size = os.fstat(fh.fileno()).st_size
    except Exception:  # a truncated or foreign file: mcap raises several types
        return None
    name = os.path.basename(path)[:-len(SUFFIX)]
    if meta.get("id") != name or not isinstance(meta.get("all_codes"), list):
        meta["id"] = name
    try:
        return {"id": name, "format": FORMAT, "all_codes": [str(c) for c in meta["all_codes"]],
                "fault_codes": [], "sources": {str(k): [str(s) for s in v] for k, v in dict(meta["sources"]).items()},
                "created_ns": int(meta["created_ns"]), "started_ns": int(meta["started_ns"]),
                "ended_ns": int(meta["ended_ns"]), "duration_sec": float(meta["duration_sec"]),
                "topics": [{"topic": str(t["topic"]), "type": str(t["type"])} for t in meta["topics"]],
                "messages": int(meta["messages"]), "path": path, "size": size}
    except (KeyError, TypeError, ValueError, AttributeError):
        return None


def _unlink(path: str) -> None:
    remove(path, log, "could not delete")


def _fsync_dir(directory: str) -> None:
    fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
