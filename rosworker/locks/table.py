"""The lock table: SOVD locks (ISO 17978-3 §7.17), held by the ROS worker so that every HTTP worker agrees on them.

As medkit's ``LockManager`` (``core/managers/lock_manager.cpp``): at most one lock per entity (an
app or a component), owned by one client, with ``scopes`` (none: every collection), an expiry
(``lock_expiration`` seconds, at most ``locking_default_max_expiration``), ids ``lock_<n>``.
Acquiring an entity that another client holds is ``lock-conflict`` unless ``break_lock`` is asked
(every lock is breakable, as medkit's defaults); an expired lock is as good as none.  Extending and
releasing are for the owner only (``lock-not-owner``).  Who may write what under these locks is
checked by the HTTP side, in one place for every write (``app/locks/``), from a copy of this table.

- Expiry runs on the monotonic clock (``time.monotonic``, the same clock in every process of the
  machine): a lock's deadline is a monotonic time; a sweep every ``locking_cleanup_interval``
  drops the expired ones and counts them.  A step of the wall clock changes nothing.
- Every change is written to ``<runtime_dir>/locks.json`` (atomically, 0600) and then announced
  through the ``locks`` generation (``common/generations.py``) before its answer goes out: the
  HTTP workers read their copy again before their next write check.
- A ROS worker that was restarted (killed, crashed) takes the table back from that file: the locks
  survive it, with their deadlines.  A new gateway starts with none (medkit keeps locks in memory
  only), and so does a worker after a reboot (the file names the boot it was written in).

Commands (``ipc/PROTOCOL.md``): ``lock_acquire``, ``lock_extend``, ``lock_release``, ``lock_list``.
Counters (``x-medkit-locks`` of ``/health``): locks held, acquired, released, broken, expired.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

from common.generations import Generations
from common.process import remove, write_atomic
from ipc.errors import IpcError

log = logging.getLogger("sovd.rosworker.locks")

FILE_NAME = "locks.json"
COLLECTIONS = ("apps", "components")
# medkit's scopes (lock_manager.hpp's valid_lock_scopes), and this gateway's triggers.
SCOPES = ("data", "operations", "configurations", "faults", "modes", "scripts", "bulk-data", "logs",
          "cyclic-subscriptions", "triggers")
OWNER_MAX = 256
SLOT = "locks"


@dataclass
class Lock:
    id: str
    collection: str
    entity_id: str
    owner: str
    scopes: list[str]
    expires: float          # time.monotonic() deadline
    expiration: int         # the seconds last asked for

    def wire(self, now: float) -> dict[str, Any]:
        return {**asdict(self), "expires_in": max(0.0, self.expires - now)}


def boot_id() -> str:
    try:
        with open("/proc/sys/kernel/random/boot_id") as fh:
            return fh.read().strip()
    except OSError:
        return ""


class LockTable:
    """The locks, their commands, their file and their counters (used on the ROS thread only)."""

    def __init__(self, runtime_dir: str, stats: Any, *, max_locks: int, max_expiration: int,
                 cleanup_interval: float, call_later: Callable[[float, Callable[[], None]], Any],
                 restore: bool, clock: Callable[[], float] = time.monotonic):
        self.path = os.path.join(runtime_dir, FILE_NAME)
        self.generations = Generations(runtime_dir)
        self.stats = stats
        self.max_locks = max_locks
        self.max_expiration = max_expiration
        self.cleanup_interval = cleanup_interval
        self.call_later = call_later
        self.clock = clock
        self.locks: dict[tuple[str, str], Lock] = {}
        self.next_id = 1
        if restore:
            self._load()
        else:
            self._discard()
        self._changed()
        self.commands: dict[str, Callable[[Any], None]] = {
            "lock_acquire": self.acquire, "lock_extend": self.extend, "lock_release": self.release,
            "lock_list": self.list,
        }

    # ---- life -----------------------------------------------------------------------------------
    def start(self) -> None:
        def tick() -> None:
            self.call_later(self.cleanup_interval, tick)
            self.sweep()
        self.call_later(self.cleanup_interval, tick)

    def shutdown(self) -> None:
        self._save()

    # ---- commands (ROS thread) ------------------------------------------------------------------
    def acquire(self, task) -> None:
        args = task.args
        key = self._entity(args)
        owner = _owner(args)
        expiration = self._expiration(args)
        scopes = _scopes(args)
        breaking = args.get("break_lock", False)
        if not isinstance(breaking, bool):
            raise IpcError("bad-request", "break_lock: expected true or false")
        now = self.clock()
        held = self.locks.get(key)
        if held is not None and held.expires <= now:
            self._expire(key)
            held = None
        if held is not None and not breaking:
            raise IpcError("lock-conflict", f"Entity is already locked by client '{held.owner}'",
                           {"existing_lock_id": held.id})
        if held is None and len(self.locks) >= self.max_locks:
            raise IpcError("locks-full", f"The gateway holds {self.max_locks} locks, its most (max_locks)",
                           {"max_locks": self.max_locks})
        if held is not None:
            self.stats.locks_broken += 1
            log.info("lock %s on %s/%s of %s broken by %s", held.id, key[0], key[1], held.owner, owner)
        lock = Lock(f"lock_{self.next_id}", key[0], key[1], owner, scopes, now + expiration, expiration)
        self.next_id += 1
        self.locks[key] = lock
        self.stats.locks_acquired += 1
        self._changed()
        task.reply(lock.wire(now))

    def extend(self, task) -> None:
        key = self._entity(task.args)
        lock = self._owned(task.args, key)
        expiration = self._expiration(task.args)
        now = self.clock()
        lock.expires = now + expiration
        lock.expiration = expiration
        self._changed()
        task.reply(lock.wire(now))

    def release(self, task) -> None:
        key = self._entity(task.args)
        self._owned(task.args, key)
        del self.locks[key]
        self.stats.locks_released += 1
        self._changed()
        task.reply({})

    def list(self, task) -> None:
        now = self.clock()
        task.reply({"items": [lock.wire(now) for lock in self.locks.values() if lock.expires > now]})

    def sweep(self) -> None:
        now = self.clock()
        expired = [key for key, lock in self.locks.items() if lock.expires <= now]
        for key in expired:
            self._expire(key)
        if expired:
            self._changed()

    # ---- checks ---------------------------------------------------------------------------------
    def _entity(self, args: dict) -> tuple[str, str]:
        collection, entity_id = args.get("collection"), args.get("entity_id")
        if collection not in COLLECTIONS:
            raise IpcError("bad-request", "collection: expected apps or components")
        if not isinstance(entity_id, str) or not 1 <= len(entity_id) <= 256:
            raise IpcError("bad-request", "entity_id: expected a string of 1 to 256 characters")
        return collection, entity_id

    def _expiration(self, args: dict) -> int:
        value = args.get("lock_expiration")
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= self.max_expiration:
            raise IpcError("bad-request", f"lock_expiration: expected whole seconds from 1 to {self.max_expiration}")
        return value

    def _owned(self, args: dict, key: tuple[str, str]) -> Lock:
        owner = _owner(args)
        lock = self.locks.get(key)
        if lock is not None and lock.expires <= self.clock():
            self._expire(key)
            self._changed()
            lock = None
        if lock is None or lock.id != args.get("lock_id"):
            raise IpcError("lock-not-found", "Lock not found",
                           {"lock_id": str(args.get("lock_id"))[:300], "entity_id": key[1]})
        if lock.owner != owner:
            raise IpcError("lock-not-owner", "Lock is owned by a different client", {"lock_id": lock.id})
        return lock

    def _expire(self, key: tuple[str, str]) -> None:
        lock = self.locks.pop(key)
        self.stats.locks_expired += 1
        log.info("lock %s on %s/%s of %s expired", lock.id, key[0], key[1], lock.owner)

    # ---- the file and the announcement ----------------------------------------------------------
    def _changed(self) -> None:
        self.stats.locks_held = len(self.locks)
        self._save()
        self.generations.bump(SLOT)

    def _save(self) -> None:
        state = {"boot_id": boot_id(), "next_id": self.next_id, "locks": [asdict(lock) for lock in self.locks.values()]}
        try:
            write_atomic(self.path, json.dumps(state).encode())
        except OSError as exc:
            log.error("locks: cannot write %s (%s): a restarted ROS worker would start without them", self.path, exc)

    def _discard(self) -> None:
        remove(self.path, log, "locks: cannot remove")

    def _load(self) -> None:
        try:
            with open(self.path, "rb") as fh:
                state = json.loads(fh.read())
        except FileNotFoundError:
            return
        except (OSError, ValueError) as exc:
            log.error("locks: %s is unreadable (%s); starting without locks", self.path, exc)
            return
        if not isinstance(state, dict) or state.get("boot_id") != boot_id():
            log.info("locks: %s is from another boot of the machine; starting without locks", self.path)
            return
        next_id = state.get("next_id")
        self.next_id = next_id if isinstance(next_id, int) and next_id > 0 else 1
        for item in state.get("locks") or []:
            try:
                lock = Lock(**item)
            except TypeError:
                continue
            if lock.collection in COLLECTIONS and isinstance(lock.expires, (int, float)):
                self.locks[(lock.collection, lock.entity_id)] = lock
        log.info("locks: %d taken back from before the restart", len(self.locks))


def _owner(args: dict) -> str:
    owner = args.get("owner")
    if not isinstance(owner, str) or not 1 <= len(owner) <= OWNER_MAX:
        raise IpcError("bad-request", f"owner: expected a string of 1 to {OWNER_MAX} characters")
    return owner


def _scopes(args: dict) -> list[str]:
    scopes = args.get("scopes", [])
    if not isinstance(scopes, list) or any(s not in SCOPES for s in scopes):
        raise IpcError("bad-request", "scopes: expected a list of " + ", ".join(SCOPES))
    return list(dict.fromkeys(scopes))
