"""Small process helpers shared by the supervisor, the ROS worker and the HTTP workers.

- :func:`package_version`: the installed ``sovd-gateway`` version (``--version``, ``/``,
  the ROS worker's ``ping``).
- :func:`lock_pidfile`: the exclusive ``flock`` that makes one supervisor (``supervisor.lock``)
  and one ROS worker (``rosworker.lock``) per runtime directory; the file holds the owner's pid.
- :func:`write_atomic`: a small file of the runtime directory replaced in one step, 0600
  (``supervisor.json``, the restart state), so a reader never sees half of it; :func:`remove`:
  a file deleted, a missing one being no error.
- :class:`PerProcess`: a value made on first use in each process, forgotten in a child
  after ``fork()`` (``os.register_at_fork``), so nobody uses the parent's sockets, maps or
  events: gunicorn forks the HTTP workers from a master that may already hold some.

Only the standard library; each function runs on its caller's thread.
"""

from __future__ import annotations

import fcntl
import functools
import logging
import os
import threading
import weakref
from collections.abc import Callable
from importlib import metadata
from typing import IO, Generic, TypeVar

T = TypeVar("T")
DISTRIBUTION = "sovd-gateway"


@functools.cache  # reading package metadata costs ~0.4 ms; it cannot change in a running process
def package_version() -> str:
    """The installed version, or ``0.0.0`` when running from a checkout that is not installed."""
    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return "0.0.0"


class PidfileHeld(BlockingIOError):
    """Another process holds the lock; ``holder`` is the pid it wrote (or ``""``)."""

    def __init__(self, path: str, holder: str):
        super().__init__(f"{path} is locked by pid {holder or '?'}")
        self.path = path
        self.holder = holder


def lock_pidfile(path: str) -> IO[str]:
    """Take an exclusive ``flock`` on ``path`` (0600) without waiting and write our pid into it.

    Returns the open file: the lock lasts as long as it stays open (the kernel drops it when
    the process dies).  Raises :class:`PidfileHeld` when another process holds it.
    """
    fh = open(path, "a+")  # noqa: SIM115 - held for the owner's lifetime
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        fh.seek(0)
        holder = fh.read().strip()
        fh.close()
        raise PidfileHeld(path, holder) from None
    except BaseException:
        fh.close()
        raise
    os.chmod(path, 0o600)
    fh.seek(0)
    fh.truncate()
    fh.write(str(os.getpid()))
    fh.flush()
    return fh


def write_atomic(path: str, data: bytes) -> None:
    """Replace ``path`` by ``data`` in one step (write ``path.tmp``, rename), private (0600).

    Raises OSError; the caller decides whether a failed write matters.
    """
    tmp = path + ".tmp"
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o600)
    with os.fdopen(fd, "wb") as fh:
        os.fchmod(fd, 0o600)  # an older copy may have been made with other bits, whatever the umask
        fh.write(data)
    os.replace(tmp, path)


def remove(path: str, log: logging.Logger, what: str) -> None:
    """Delete ``path``; gone already is fine, any other failure is logged (a warning: ``what path: error``)."""
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
    except OSError as exc:
        log.warning("%s %s: %s", what, path, exc)


_instances: weakref.WeakSet[PerProcess] = weakref.WeakSet()
_LOCKS = threading.Lock()  # guards the making of each instance's lock


class PerProcess(Generic[T]):
    """``make()``'s value, made once per process on first :meth:`get` (thread-safe).

    A child after ``fork()`` starts without it: the parent's value (a ZeroMQ context, a
    socket, a memory map, an event) is dropped there, never used and never closed, since
    closing may act on the parent's resource.  ``close`` (if given) ends the value of the
    process that made it, in :meth:`reset`.
    """

    def __init__(self, make: Callable[[], T], close: Callable[[T], None] | None = None):
        self._make = make
        self._close = close
        self._value: T | None = None
        self._lock: threading.Lock | None = None  # made on first use: the patched kind in an HTTP worker
        _instances.add(self)

    def _guard(self) -> threading.Lock:
        lock = self._lock
        if lock is None:
            with _LOCKS:  # never held across anything that could switch
                lock = self._lock
                if lock is None:
                    lock = self._lock = threading.Lock()
        return lock

    def get(self) -> T:
        value = self._value
        if value is None:
            with self._guard():
                value = self._value
                if value is None:
                    value = self._value = self._make()
        return value

    def peek(self) -> T | None:
        """This process's value, or None when none was made (nothing is made here)."""
        return self._value

    def reset(self) -> None:
        """Forget (and ``close``) this process's value; the next :meth:`get` makes a new one."""
        with self._guard():
            value, self._value = self._value, None
        if value is not None and self._close is not None:
            self._close(value)

    def _forget(self) -> None:
        self._value = None
        self._lock = None  # another thread of the parent may have held it at the fork


def _after_fork_in_child() -> None:
    global _LOCKS
    _LOCKS = threading.Lock()
    for instance in list(_instances):
        instance._forget()


os.register_at_fork(after_in_child=_after_fork_in_child)
