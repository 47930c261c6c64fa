"""The files the supervisor keeps in the runtime directory for the HTTP side (beside the IPC sockets).

- ``metrics/`` (0700): prometheus_client's per-process files of the HTTP
  workers (``app/core/metrics.py``).  Emptied by :func:`prepare` at start-up, as
  prometheus_client's multiprocess mode prescribes; gunicorn is started with
  ``PROMETHEUS_MULTIPROC_DIR`` pointing at it.
- ``ratelimit.buckets``: the token buckets all HTTP workers share
  (``app/ratelimit.py``); removed at start-up, so a restart starts with full
  buckets and the current settings.
- ``supervisor.json``: what the supervisor knows that the HTTP side exports
  as metrics (ROS-worker restarts, when the running one started), replaced
  atomically by :func:`write_supervisor_state` at each ROS-worker start and
  read by :func:`read_supervisor_state` at each scrape.

The supervisor calls :func:`prepare` once, holding its lock (one gateway per
runtime directory), before it starts any child.  Nothing here imports more
than the standard library and ``common/process.py``.
"""

from __future__ import annotations

import json
import os
import shutil
from typing import Any

from common.process import write_atomic

METRICS_DIR = "metrics"
RATELIMIT_FILE = "ratelimit.buckets"
SUPERVISOR_STATE = "supervisor.json"
MULTIPROC_ENV = "PROMETHEUS_MULTIPROC_DIR"


def metrics_dir(runtime_dir: str) -> str:
    return os.path.join(runtime_dir, METRICS_DIR)


def prepare(runtime_dir: str) -> str:
    """Empty (or create, 0700) the metrics directory; drop the last run's buckets and state.

    Returns the metrics directory, for ``PROMETHEUS_MULTIPROC_DIR``.
    """
    path = metrics_dir(runtime_dir)
    if os.path.isdir(path) and not os.path.islink(path):
        for entry in os.scandir(path):
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path, ignore_errors=True)
            else:
                os.unlink(entry.path)
    else:
        if os.path.lexists(path):
            os.unlink(path)
        os.mkdir(path, 0o700)
    os.chmod(path, 0o700)
    for name in (RATELIMIT_FILE, SUPERVISOR_STATE):
        try:
            os.unlink(os.path.join(runtime_dir, name))
        except FileNotFoundError:
            pass
    return path


def write_supervisor_state(runtime_dir: str, restarts: int, worker_started_at: float,
                           worker_pid: int) -> None:
    """One small JSON file, replaced atomically (a reader never sees half of it)."""
    write_atomic(os.path.join(runtime_dir, SUPERVISOR_STATE),
                 json.dumps({"ros_worker_restarts": restarts, "ros_worker_started_at": worker_started_at,
                             "ros_worker_pid": worker_pid}).encode())


def read_supervisor_state(runtime_dir: str) -> dict[str, Any] | None:
    """The supervisor's state, or None (no supervisor: a test app)."""
    try:
        with open(os.path.join(runtime_dir, SUPERVISOR_STATE)) as fh:
            state = json.load(fh)
    except (OSError, ValueError):
        return None
    return state if isinstance(state, dict) else None
