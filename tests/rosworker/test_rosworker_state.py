"""rosworker/core/state.py: the restart state's file (round trip, mode, damage), its writer thread, discard.

Real files in a temporary runtime dir and the real writer thread.  That a
restarted ROS worker keeps its pool and its subscriptions through this file is
checked through a real gateway in tests/rosworker/test_rosworker_pool.py and
tests/app/test_app_streams.py.
"""

from __future__ import annotations

import json
import os
import stat
import threading

import pytest

from rosworker.core import state as state_mod
from rosworker.core.state import RestartState
from tests.support.procs import poll_until

SUB_A = {"id": "sub_a", "topic": "/a", "interval": "fast", "expires_at_ns": 1}
SUB_B = {"id": "sub_b", "topic": "/b", "interval": "slow", "expires_at_ns": 2}


def records(*subs: dict):
    """The ``records`` callable the registry hands over: its subscriptions' JSON texts."""
    return lambda: [json.dumps(s).encode() for s in subs]


def mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


class GatedState(RestartState):
    """A RestartState whose writes wait for ``gate`` (a disk that is slow right now), and are counted."""

    def __init__(self, runtime_dir: str, post=None):
        super().__init__(runtime_dir, post=post)
        self.gate = threading.Event()
        self.writes: list[list[str]] = []

    def _write(self, topics, nodes, recs) -> None:
        self.writes.append(list(topics))
        assert self.gate.wait(10), "the test never opened the gate"
        super()._write(topics, nodes, recs)


def test_what_is_saved_loads_back(tmp_path):
    state = RestartState(str(tmp_path))  # no writer thread yet: written on the caller's thread
    state.submit(["/a", "/b"], ["/n1", "/ns/n2"], 1, records(SUB_A, SUB_B))
    assert state.load() == (["/a", "/b"], ["/n1", "/ns/n2"], [SUB_A, SUB_B])
    assert os.path.basename(state.path) == state_mod.FILE_NAME
    assert not os.path.exists(state.path + ".tmp")  # written beside, then renamed over


def test_nothing_saved_loads_empty(tmp_path):
    assert RestartState(str(tmp_path)).load() == ([], [], [])


def test_the_file_is_private_whatever_the_umask_and_an_older_copy(tmp_path):
    state = RestartState(str(tmp_path))
    with open(state.path + ".tmp", "w") as fh:  # left by a worker killed mid-write, with other bits
        fh.write("half")
    os.chmod(state.path + ".tmp", 0o666)
    old = os.umask(0)
    try:
        state.submit(["/a"], [], 1, records())
    finally:
        os.umask(old)
    assert mode(state.path) == 0o600
    assert state.load()[0] == ["/a"]


@pytest.mark.parametrize("text", [b"", b"{not json", b"\xff\xfe\x00garbage", b"[1, 2, 3]", b"null", b'"a string"',
                                  b'{"topics": "/a", "nodes": 7, "subscriptions": {"id": "x"}}'])
def test_a_damaged_file_loads_empty(tmp_path, text):
    state = RestartState(str(tmp_path))
    with open(state.path, "wb") as fh:
        fh.write(text)
    assert state.load() == ([], [], [])


def test_items_of_the_wrong_kind_are_left_out_and_the_lists_are_capped(tmp_path, monkeypatch):
    state = RestartState(str(tmp_path))
    with open(state.path, "w") as fh:
        json.dump({"topics": ["/a", 7, None, "/b", ["/c"]], "nodes": [{"n": 1}, "/n"],
                   "subscriptions": [SUB_A, "sub_b", 3, SUB_B]}, fh)
    assert state.load() == (["/a", "/b"], ["/n"], [SUB_A, SUB_B])
    monkeypatch.setattr(state_mod, "MAX_ITEMS", 2)
    with open(state.path, "w") as fh:
        json.dump({"topics": ["/1", "/2", "/3"], "nodes": [], "subscriptions": [SUB_A, SUB_B, SUB_A]}, fh)
    assert state.load() == (["/2", "/3"], [], [SUB_B, SUB_A])  # the newest kept


def test_discard_removes_the_file_and_a_half_written_one(tmp_path):
    state = RestartState(str(tmp_path))
    state.submit(["/a"], [], 1, records(SUB_A))
    with open(state.path + ".tmp", "w") as fh:
        fh.write("half")
    state.discard()
    assert not os.path.exists(state.path) and not os.path.exists(state.path + ".tmp")
    assert state.load() == ([], [], [])
    state.discard()  # nothing there: not an error


def test_the_writer_coalesces_what_comes_during_a_write_and_answers_each_caller_after_it(tmp_path):
    posted: list = []
    state = GatedState(str(tmp_path), post=lambda fn: (posted.append(threading.current_thread().name), fn()))
    answered: list[str] = []
    state.start()
    try:
        state.submit(["/1"], [], 1, records(), then=lambda: answered.append("1"))
        poll_until(lambda: state.writes == [["/1"]], 5, message="the first write under way")
        for n in "234":  # all three arrive while the first write waits on the disk
            state.submit([f"/{n}"], [], int(n), records(), then=lambda n=n: answered.append(n))
        assert answered == []  # nobody is answered before their state is written
        state.gate.set()
        poll_until(lambda: len(answered) == 4, 5, message="every caller answered")
        assert state.writes == [["/1"], ["/4"]]  # 2 and 3 were never written: 4 is newer
        assert answered == ["1", "2", "3", "4"]
        assert state.load()[0] == ["/4"]
        assert set(posted) == {"restart-state-writer"}  # handed to `post` from the writer thread
    finally:
        state.gate.set()
        state.close(5)


def test_an_unchanged_state_is_not_handed_over_again(tmp_path):
    calls = []

    def recs():
        calls.append(1)
        return [json.dumps(SUB_A).encode()]

    state = GatedState(str(tmp_path))
    state.gate.set()
    state.start()
    try:
        state.submit(["/a"], ["/n"], 5, recs)
        poll_until(lambda: state.writes, 5, message="the first write")
        answered = []
        state.submit(["/a"], ["/n"], 5, recs, then=lambda: answered.append(1))
        assert answered == [1]           # already written: answered at once, on this thread
        assert len(calls) == 1           # the records were not even asked for again
        state.submit(["/a"], ["/n"], 6, recs)  # a new version of the subscriptions
        poll_until(lambda: len(state.writes) == 2, 5, message="the second write")
        assert len(calls) == 2
    finally:
        state.close(5)


def test_close_writes_what_is_pending_and_later_submits_write_at_once(tmp_path):
    state = GatedState(str(tmp_path))
    state.start()
    state.submit(["/1"], [], 1, records())
    poll_until(lambda: state.writes, 5, message="a write under way")
    state.submit(["/2"], [], 2, records(SUB_A))  # pending behind it
    state.gate.set()
    state.close(5)
    assert state.load() == (["/2"], [], [SUB_A])
    answered = []
    state.submit(["/3"], [], 3, records(), then=lambda: answered.append(1))
    assert state.load()[0] == ["/3"] and answered == [1]  # on this thread, before submit returns


def test_a_failed_write_is_logged_and_the_caller_answered_all_the_same(tmp_path, caplog):
    gone = tmp_path / "gone"  # the runtime dir was removed under the worker
    state = RestartState(str(gone))
    state.start()
    answered = threading.Event()
    try:
        state.submit(["/a"], [], 1, records(), then=answered.set)
        assert answered.wait(5)
        poll_until(lambda: "could not save the restart state" in caplog.text, 5, message="the warning")
        assert not gone.exists()
    finally:
        state.close(5)
