"""Change counters that the gateway's processes share through one small file in the runtime dir.

``<runtime_dir>/generations`` (0600) holds one 64-bit value per :data:`SLOTS` name.  A process that
changes a shared table writes a fresh value into its slot *before* it answers the request that
made the change; a process that keeps a copy of that table reads the slot (a few hundred
nanoseconds, no system call) before it uses its copy and fetches the table again when the value
is not the one it fetched at.  So a change is seen by every process from the moment it was
answered, without asking anyone on the way:

- ``locks``: the ROS worker's lock table (``rosworker/locks/``), copied by every HTTP worker for
  the lock check of each write (``app/locks/``);
- ``revocations``: the revoked tokens in ``access.db`` (``app/auth/revocations.py``), written and
  copied by the HTTP workers.

A new value is random, never the one in the slot, so two writers need no lock between them and a
restarted process never repeats a value its predecessor wrote.  Eight aligned bytes are written
in one store; a reader that caught a torn value only fetches once more.
"""

from __future__ import annotations

import functools
import mmap
import os
import struct

from common.process import PerProcess

FILE_NAME = "generations"
SLOTS = {"locks": 0, "revocations": 1}
SIZE = 4096
_VALUE = struct.Struct("<Q")


class _Mapped:
    @classmethod
    def open(cls, path: str) -> _Mapped:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
        try:
            if os.fstat(fd).st_size < SIZE:
                os.ftruncate(fd, SIZE)  # zeros: no copy was fetched at 0, every reader fetches once
            return cls(fd, mmap.mmap(fd, SIZE))
        except BaseException:
            os.close(fd)
            raise

    def __init__(self, fd: int, mapped: mmap.mmap):
        self.fd = fd
        self.map = mapped

    def close(self) -> None:
        self.map.close()
        os.close(self.fd)


class Generations:
    """The shared counters of one runtime dir (mapped on first use in each process)."""

    def __init__(self, runtime_dir: str):
        self.path = os.path.join(runtime_dir, FILE_NAME)
        self._file: PerProcess[_Mapped] = PerProcess(functools.partial(_Mapped.open, self.path), _Mapped.close)

    def read(self, name: str) -> int:
        return _VALUE.unpack_from(self._file.get().map, SLOTS[name] * _VALUE.size)[0]

    def bump(self, name: str) -> int:
        """Write a new value into ``name``'s slot (before answering the change it announces)."""
        mapped = self._file.get().map
        offset = SLOTS[name] * _VALUE.size
        old = _VALUE.unpack_from(mapped, offset)[0]
        new = old
        while new in (old, 0):
            new = int.from_bytes(os.urandom(8), "little")
        _VALUE.pack_into(mapped, offset, new)
        return new

    def close(self) -> None:
        self._file.reset()
