"""common/process.py: the version, the pidfile lock, the atomic write and per-process values."""

from __future__ import annotations

import os
import subprocess
import sys
from importlib import metadata

import pytest

from common import process
from common.harness.procs import REPO


def test_package_version_is_the_installed_one():
    assert process.package_version() == metadata.version("sovd-gateway")


HOLD = """
import sys, time
from common.process import lock_pidfile
fh = lock_pidfile(sys.argv[1])
print("held", flush=True)
sys.stdin.read()
"""


def test_a_pidfile_held_by_another_process_names_it_and_is_free_once_it_dies(tmp_path):
    path = str(tmp_path / "x.lock")
    holder = subprocess.Popen([sys.executable, "-c", HOLD, path], cwd=REPO, stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(process.PidfileHeld) as info:
            process.lock_pidfile(path)
        assert info.value.holder == str(holder.pid)
        assert isinstance(info.value, BlockingIOError)
    finally:
        holder.stdin.close()
        holder.wait(30)
    fh = process.lock_pidfile(path)  # the kernel dropped the dead holder's lock
    try:
        assert open(path).read() == str(os.getpid())
        assert os.stat(path).st_mode & 0o777 == 0o600
    finally:
        fh.close()


def test_write_atomic_replaces_the_file_privately(tmp_path):
    path = str(tmp_path / "state.json")
    with open(path, "w") as fh:
        fh.write("old, and world-readable")
    os.chmod(path, 0o644)
    old_umask = os.umask(0)
    try:
        process.write_atomic(path, b'{"new": true}')
    finally:
        os.umask(old_umask)
    assert open(path, "rb").read() == b'{"new": true}'
    assert os.stat(path).st_mode & 0o777 == 0o600
    assert os.listdir(tmp_path) == ["state.json"]


class Thing:
    made = 0

    def __init__(self):
        Thing.made += 1
        self.pid = os.getpid()
        self.closed = False

    def close(self):
        self.closed = True


def test_per_process_makes_once_per_process_and_a_forked_child_never_uses_the_parents():
    per = process.PerProcess(Thing, Thing.close)
    assert per.peek() is None
    first = per.get()
    assert per.get() is first and Thing.made >= 1
    read, write = os.pipe()
    child = os.fork()
    if child == 0:  # the child: report what it sees, without running pytest's teardown
        try:
            seen = per.peek()
            mine = per.get()
            ok = seen is None and mine is not first and mine.pid == os.getpid() and not first.closed
            os.write(write, b"ok" if ok else b"bad")
        finally:
            os._exit(0)
    os.close(write)
    answer = os.read(read, 16)
    os.close(read)
    os.waitpid(child, 0)
    assert answer == b"ok"
    assert per.get() is first and not first.closed  # the parent's value is untouched
    per.reset()
    assert first.closed and per.peek() is None
    assert per.get() is not first
