"""The events channel: what the ROS worker streams to the HTTP workers (cyclic subscriptions, faults, triggers).

Transport: a ZeroMQ XPUB socket that the ROS worker binds on
``ipc://<runtime_dir>/rosworker-events.sock`` (0600, like the others), and one
SUB socket per HTTP worker.  Every message is a multipart whose first frame
is its key; SUB sockets filter on key prefixes, so an HTTP worker receives
only the keys its open streams watch, once per tick however many of its
streams watch them.  The wire format is documented in ``ipc/PROTOCOL.md``.

- data ``d|<interval>|<bytes mode>|<topic>|`` + msgpack meta + the JSON text of
  the message (``{}`` without data): one per tick per watched topic.  meta is a
  ``sample`` answer without ``data_json`` plus ``ts`` (ns, the tick's time), or
  ``{"ts", "error": <wire error>}`` when a GET would answer an error;
- control ``c|<subscription id>`` + msgpack ``{"event": "updated" | "deleted" |
  "expired", "id", "key", "interval", "expires_in"}``, and ``c|shutdown`` when the
  ROS worker stops;
- triggers ``t|g|<bytes mode>|<source>|<digest>|`` + msgpack ``{"ts", "fired": [[id, seq,
  last], ...], "error"?}`` + the change's JSON: one frame per change of what a group of
  triggers observes (one source and target), however many of them fired on it; and
  ``t|c|<id>|`` + msgpack ``{"event", "id"}`` when one is deleted or expires;
- faults ``f|`` + msgpack ``{"id", "event_type", "fault", "timestamp"}``;
- heartbeat ``h|`` + msgpack ``{"pid", "t"}`` every second;
- confirmation: a one-frame message, the subscribed prefix itself, answers every
  subscription an HTTP worker makes (the XPUB is verbose: the ROS thread reads
  each one).  The XPUB applied the subscription before handing it over, so
  whoever receives the confirmation receives everything of that prefix sent
  after it: an event stream opens only then (``app/sse/channel.py``).  A reader
  passes over one-frame messages it does not wait for.
"""

from __future__ import annotations

import hashlib
import os

EVENTS_SOCKET_NAME = "rosworker-events.sock"
# SOVD cyclic-subscription intervals, in seconds.
INTERVALS = {"fast": 0.05, "normal": 0.2, "slow": 0.5}
CONTROL_KEY = b"c|"
HEARTBEAT_KEY = b"h|"
DATA_PREFIX = b"d|"
# faults (rosworker/faults/manager.py): ``f|`` + msgpack {"id", "event_type", "fault", "timestamp"}, one per event
FAULT_KEY = b"f|"
# Per subscriber: frames queued for a slow HTTP worker beyond this are dropped by ZeroMQ,
# never buffered without bound (a worker that keeps up holds a handful).
HIGH_WATER = 10000


def endpoint(runtime_dir: str) -> str:
    return "ipc://" + os.path.join(runtime_dir, EVENTS_SOCKET_NAME)


def endpoint_beside(work_endpoint: str) -> str:
    """The events socket beside a work socket (``.../rosworker.sock`` → ``.../rosworker-events.sock``)."""
    head, sep, _ = work_endpoint.rpartition("/")
    return f"{head}{sep}{EVENTS_SOCKET_NAME}" if sep else work_endpoint + "-events"


def data_key(interval: str, mode: str, topic: str) -> bytes:
    """The key of a topic's frames at one interval and bytes mode (topic names hold no ``|``)."""
    return f"d|{interval}|{mode}|{topic}|".encode()


# Triggers (rosworker/triggers/registry.py; their frames above): HTTP workers subscribe to ``t|c|`` and to
# the group key of each trigger their open streams watch (``trigger_group_key``); the fleet link to ``t|g|``.
TRIGGER_GROUP_PREFIX = b"t|g|"
TRIGGER_CONTROL_PREFIX = b"t|c|"


def trigger_group_key(source: str, mode: str, target: str) -> bytes:
    """The key of the events of every trigger that observes ``target`` of the collection ``source`` with
    payloads in bytes ``mode`` (both sides compute it from the trigger's fields).  The target goes in as a
    digest: a topic may be long, and an entity's scope is JSON that may hold ``|``."""
    digest = hashlib.blake2b(f"{source}\0{target}".encode("utf-8", "surrogatepass"), digest_size=8).hexdigest()
    return f"t|g|{mode}|{source}|{digest}|".encode()


def trigger_control_key(trigger_id: str) -> bytes:
    return TRIGGER_CONTROL_PREFIX + trigger_id.encode() + b"|"
