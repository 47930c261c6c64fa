"""Bulk data in the ROS worker: recordings of what led up to each confirmed fault (issue 32).

- ``recorder.py``: the recorded topics' subscriptions (shared with the pool), the ring
  buffer, the recording a confirmed fault opens (ROS thread);
- ``writer.py``: the writer thread, the MCAP files, the index rebuilt from the directory;
- ``msgdefs.py``: a type's complete message definition, for the files' schemas.

Its commands (``ipc/PROTOCOL.md`` "Bulk data"): ``bulk_rosbags`` lists every recording
(the HTTP side scopes them to an entity by their faults' sources), ``bulk_rosbag_get``
gives one (by recording id, or a fault code: that fault's newest, medkit's older URLs).
The HTTP workers read the files themselves (``app/bulk_data/``); uploaded bulk-data files
never reach the ROS worker.

With ``fault_rosbag_enabled`` off or no topic named, nothing is subscribed and no timer
runs; the recordings already on disk are still listed and served.
"""

from __future__ import annotations

import logging
from typing import Any

from common import settings as config
from ipc.errors import IpcError

from ..core.family import Core, Family
from .recorder import Recorder
from .writer import RecordingStore

log = logging.getLogger("sovd.rosworker.bulk_data")

ID_MAX = 256
CLOSE_WAIT = 5.0  # seconds the writer gets at shutdown to finish what is queued


def snapshot(recording: dict[str, Any]) -> dict[str, Any]:
    """A recording as a snapshot of its fault's detail (medkit's ``Snapshot`` of type rosbag)."""
    return {"type": "rosbag", "name": f"rosbag_{recording['id']}", "bulk_data_id": recording["id"],
            "size_bytes": recording["size"], "duration_sec": recording["duration_sec"],
            "format": recording["format"], "captured_at_ns": recording["created_ns"],
            "topics": [t["topic"] for t in recording["topics"]], "messages": recording["messages"]}


class BulkData(Family):
    """The family: its recorder, its store of recordings, its commands.

    What it needs of the others goes through the core: the recorded topics' subscriptions are
    read by the data family's pool (``core.shared_topics``); the faults family tells it of each
    confirmation and lists its recordings among a fault's snapshots (``core.extend``:
    ``fault_confirmed``, ``fault_snapshots``)."""

    name = "bulk_data"

    def __init__(self) -> None:
        super().__init__()
        self.recorder: Recorder | None = None
        self.store: RecordingStore | None = None

    def start(self, core: Core) -> None:
        """Build, load the index, register with the core, subscribe (ROS thread, before the loop)."""
        cfg, stats = core.cfg, core.stats
        self.store = RecordingStore(config.rosbag_dir(cfg), stats,
                                    max_total_bytes=cfg.fault_rosbag_max_total_mb * 2**20,
                                    max_per_fault=cfg.fault_rosbag_max_bags_per_fault)
        self.store.load()
        self.store.start()
        topics = config.names(cfg.fault_rosbag_topics) if cfg.fault_rosbag_enabled else []
        stats.rosbag_buffer_cap_mb = cfg.fault_rosbag_max_buffer_mb
        self.recorder = Recorder(core.node, core.executor, stats, core.endpoints, core.shared_topics,
                                 self.store.submit, topics=topics,
                                 duration_s=cfg.fault_rosbag_duration_s,
                                 duration_after_s=cfg.fault_rosbag_duration_after_s,
                                 max_buffer_bytes=cfg.fault_rosbag_max_buffer_mb * 2**20)
        if topics:
            core.extend("fault_confirmed", self.recorder.on_confirmed)
            self.recorder.start()
        elif cfg.fault_rosbag_enabled:
            log.warning("fault_rosbag_enabled is on but fault_rosbag_topics names no topic: nothing is recorded")
        core.extend("fault_snapshots", lambda code: [snapshot(r) for r in self.store.of_fault(code)])
        self.commands = {"bulk_rosbags": self._list, "bulk_rosbag_get": self._get}
        if cfg.debug_commands:
            self.commands["bulk_debug_pause"] = self._debug_pause

    def shutdown(self) -> None:
        """After the data family's (the pool's; the families shut down in reverse name order): close an
        open recording, unsubscribe, let the writer finish."""
        if self.recorder is not None:
            self.recorder.shutdown()
        if self.store is not None:
            self.store.close(CLOSE_WAIT)

    # ---- commands --------------------------------------------------------------------------------
    def _list(self, task) -> None:
        task.reply({"items": self.store.listing()})

    def _get(self, task) -> None:
        wanted = task.args.get("id")
        if not isinstance(wanted, str) or not 0 < len(wanted) <= ID_MAX:
            raise IpcError("bad-request", f"id: expected a recording id of 1 to {ID_MAX} characters")
        recording = self.store.get(wanted)
        by_code = False
        if recording is None:  # medkit's older URLs name the fault: its newest recording
            newest = self.store.of_fault(wanted)
            recording, by_code = (newest[0], True) if newest else (None, False)
        if recording is None:
            raise IpcError("no-such-recording", "Bulk-data not found", {"bulk_data_id": wanted[:ID_MAX]})
        task.reply({**recording, "by_fault_code": by_code})

    def _debug_pause(self, task) -> None:
        """Test only: the writer pauses for ``seconds`` halfway through each recording it writes."""
        seconds = task.args.get("seconds")
        if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not 0 <= seconds <= 60:
            raise IpcError("bad-request", "seconds: expected 0 to 60")
        self.store.pause_s = float(seconds)
        task.reply({"pause_s": self.store.pause_s})


FAMILY = BulkData()
