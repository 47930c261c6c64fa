"""rosworker/core/state.py: the restart state's file (round trip, mode, damage), its writer thread, discard.

Real files in a temporary runtime dir and the real writer thread (``core/writer.py``, whose own rules
are in test_rosworker_writer.py).  The parts are the ones the worker has: the core's ``nodes``, the
data family's ``topics``, the subscriptions' records.  That a
restarted ROS worker keeps its pool and its subscriptions through this file is
checked through a real gateway in tests/rosworker/data/test_rosworker_pool.py and
tests/system/subscriptions/test_app_streams.py.
"""

from __future__ import annotations

import json
import os
import stat
import threading

import pytest

from common.harness.procs import poll_until
from rosworker.core import state as state_mod
from rosworker.core.state import RestartState

SUB_A = {"id": "sub_a", "topic": "/a", "interval": "fast", "expires_at_ns": 1}
SUB_B = {"id": "sub_b", "topic": "/b", "interval": "slow", "expires_at_ns": 2}


class Parts:
    """What the owners of the parts hold now: the pooled topics, the graph's nodes, the subscriptions
    (their JSON records and their version); ``asked`` counts the records asked for."""

    def __init__(self):
        self.topics: list[str] = []
        self.nodes: list[str] = []
        self.subs: list[dict] = []
        self.version = 0
        self.asked = 0

    def records(self) -> list[bytes]:
        self.asked += 1
        return [json.dumps(s).encode() for s in self.subs]

    def set(self, topics=None, nodes=None, subs=None) -> Parts:
        if topics is not None:
            self.topics = topics
        if nodes is not None:
            self.nodes = nodes
        if subs is not None:
            self.subs = subs
            self.version += 1
        return self


def made(state: RestartState) -> Parts:
    """``state`` with the worker's three parts, as the core and the families add them."""
    parts = Parts()
    state.part("nodes", lambda: parts.nodes)
    state.part("topics", lambda: parts.topics)
    state.part("subscriptions", parts.records, records=True, version=lambda: parts.version)
    return parts


def loaded(state: RestartState) -> tuple[list, list, list]:
    state.load()
    return state.loaded("topics"), state.loaded("nodes"), state.loaded("subscriptions", records=True)


def mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


class GatedState(RestartState):
    """A RestartState whose writes wait for ``gate`` (a disk that is slow right now), and are counted."""

    def __init__(self, runtime_dir: str, post=None):
        super().__init__(runtime_dir, post=post)
        self.gate = threading.Event()
        self.writes: list[list[str]] = []

    def _write_batch(self, batch) -> None:
        self.writes.append(list(dict((n, v) for n, _, v in batch["state"])["topics"]))
        assert self.gate.wait(10), "the test never opened the gate"
        super()._write_batch(batch)


def test_what_is_saved_loads_back(tmp_path):
    state = RestartState(str(tmp_path))  # no writer thread yet: written on the caller's thread
    made(state).set(["/a", "/b"], ["/n1", "/ns/n2"], [SUB_A, SUB_B])
    state.save()
    assert loaded(state) == (["/a", "/b"], ["/n1", "/ns/n2"], [SUB_A, SUB_B])
    assert os.path.basename(state.path) == state_mod.FILE_NAME
    assert not os.path.exists(state.path + ".tmp")  # written beside, then renamed over


def test_nothing_saved_loads_empty(tmp_path):
    assert loaded(RestartState(str(tmp_path))) == ([], [], [])


def test_the_file_is_private_whatever_the_umask_and_an_older_copy(tmp_path):
    state = RestartState(str(tmp_path))
    parts = made(state)
    with open(state.path + ".tmp", "w") as fh:  # left by a worker killed mid-write, with other bits
        fh.write("half")
    os.chmod(state.path + ".tmp", 0o666)
    old = os.umask(0)
    try:
        parts.set(topics=["/a"])
        state.save()
    finally:
        os.umask(old)
    assert mode(state.path) == 0o600
    assert loaded(state)[0] == ["/a"]


@pytest.mark.parametrize("text", [b"", b"{not json", b"\xff\xfe\x00garbage", b"[1, 2, 3]", b"null", b'"a string"',
                                  b'{"topics": "/a", "nodes": 7, "subscriptions": {"id": "x"}}'])
def test_a_damaged_file_loads_empty(tmp_path, text):
    state = RestartState(str(tmp_path))
    with open(state.path, "wb") as fh:
        fh.write(text)
    assert loaded(state) == ([], [], [])


def test_items_of_the_wrong_kind_are_left_out_and_the_lists_are_capped(tmp_path, monkeypatch):
    state = RestartState(str(tmp_path))
    with open(state.path, "w") as fh:
        json.dump({"topics": ["/a", 7, None, "/b", ["/c"]], "nodes": [{"n": 1}, "/n"],
                   "subscriptions": [SUB_A, "sub_b", 3, SUB_B]}, fh)
    assert loaded(state) == (["/a", "/b"], ["/n"], [SUB_A, SUB_B])
    monkeypatch.setattr(state_mod, "MAX_ITEMS", 2)
    with open(state.path, "w") as fh:
        json.dump({"topics": ["/1", "/2", "/3"], "nodes": [], "subscriptions": [SUB_A, SUB_B, SUB_A]}, fh)
    assert loaded(state) == (["/2", "/3"], [], [SUB_B, SUB_A])  # the newest kept


def test_discard_removes_the_file_and_a_half_written_one(tmp_path):
    state = RestartState(str(tmp_path))
    made(state).set(["/a"], [], [SUB_A])
    state.save()
    with open(state.path + ".tmp", "w") as fh:
        fh.write("half")
    state.discard()
    assert not os.path.exists(state.path) and not os.path.exists(state.path + ".tmp")
    assert loaded(state) == ([], [], [])
    state.discard()  # nothing there: not an error


def test_the_writer_coalesces_what_comes_during_a_write_and_answers_each_caller_after_it(tmp_path):
    posted: list = []
    state = GatedState(str(tmp_path), post=lambda fn: (posted.append(threading.current_thread().name), fn()))
    parts = made(state)
    answered: list[str] = []
    state.start()
    try:
        parts.set(topics=["/1"])
        state.save(then=lambda: answered.append("1"))
        poll_until(lambda: state.writes == [["/1"]], 5, message="the first write under way")
        for n in "234":  # all three arrive while the first write waits on the disk
            parts.set(topics=[f"/{n}"])
            state.save(then=lambda n=n: answered.append(n))
        assert answered == []  # nobody is answered before their state is written
        state.gate.set()
        poll_until(lambda: len(answered) == 4, 5, message="every caller answered")
        assert state.writes == [["/1"], ["/4"]]  # 2 and 3 were never written: 4 is newer
        assert answered == ["1", "2", "3", "4"]
        assert loaded(state)[0] == ["/4"]
        assert set(posted) == {"restart-state-writer"}  # handed to `post` from the writer thread
    finally:
        state.gate.set()
        state.close(5)


def test_an_unchanged_state_is_not_handed_over_again(tmp_path):
    state = GatedState(str(tmp_path))
    parts = made(state).set(["/a"], ["/n"], [SUB_A])
    state.gate.set()
    state.start()
    try:
        state.save()
        poll_until(lambda: state.writes, 5, message="the first write")
        answered = []
        state.save(then=lambda: answered.append(1))
        assert answered == [1]           # already written: answered at once, on this thread
        assert parts.asked == 1          # the records were not even asked for again
        parts.set(subs=[SUB_A, SUB_B])   # a new version of the subscriptions
        state.save()
        poll_until(lambda: len(state.writes) == 2, 5, message="the second write")
        assert parts.asked == 2
    finally:
        state.close(5)


def test_close_writes_what_is_pending_and_later_submits_write_at_once(tmp_path):
    state = GatedState(str(tmp_path))
    parts = made(state)
    state.start()
    parts.set(topics=["/1"])
    state.save()
    poll_until(lambda: state.writes, 5, message="a write under way")
    parts.set(topics=["/2"], subs=[SUB_A])
    state.save()  # pending behind it
    state.gate.set()
    state.close(5)
    assert loaded(state) == (["/2"], [], [SUB_A])
    answered = []
    parts.set(topics=["/3"])
    state.save(then=lambda: answered.append(1))
    assert loaded(state)[0] == ["/3"] and answered == [1]  # on this thread, before save returns


def test_a_failed_write_is_logged_and_the_caller_answered_all_the_same(tmp_path, caplog):
    gone = tmp_path / "gone"  # the runtime dir was removed under the worker
    state = RestartState(str(gone))
    made(state).set(topics=["/a"])
    state.start()
    answered = threading.Event()
    try:
        state.save(then=answered.set)
        assert answered.wait(5)
        poll_until(lambda: "could not save the restart state" in caplog.text, 5, message="the warning")
        assert not gone.exists()
    finally:
        state.close(5)
