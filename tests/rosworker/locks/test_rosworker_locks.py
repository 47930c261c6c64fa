"""The ROS worker's lock table (rosworker/locks/), with a clock of the test's own: medkit's rules,
expiry on the monotonic clock, the file a restarted worker takes back, the generation every change bumps."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest

from common.generations import Generations
from ipc import counters
from ipc.errors import IpcError
from rosworker import locks as lockmod
from tests.support.fakeworker import SimpleTask


class Clock:
    def __init__(self):
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def table(tmp_path, clock, restore=False, **kw):
    stats = SimpleNamespace(**{c.name: 0 for c in counters.section("locks", counters.ROS)})
    options = {"max_locks": 3, "max_expiration": 600, "cleanup_interval": 30, **kw}
    return lockmod.LockTable(str(tmp_path), stats, call_later=lambda *_: None, restore=restore, clock=clock,
                             **options), stats


def run(locks, cmd, **args):
    answers = []
    locks.commands[cmd](SimpleTask(args, answers.append))
    return answers[0]


def acquire(locks, owner, entity="a", **args):
    return run(locks, "lock_acquire", collection="apps", entity_id=entity, owner=owner,
               lock_expiration=args.pop("lock_expiration", 60), **args)


def test_one_lock_per_entity_breakable_and_owned(tmp_path):
    clock = Clock()
    locks, stats = table(tmp_path, clock)
    first = acquire(locks, "alice", scopes=["data", "data"])
    assert first["id"] == "lock_1" and first["scopes"] == ["data"] and first["expires_in"] == 60
    with pytest.raises(IpcError) as info:
        acquire(locks, "bob")
    assert info.value.code == "lock-conflict" and info.value.params == {"existing_lock_id": "lock_1"}
    with pytest.raises(IpcError) as info:
        acquire(locks, "alice")   # medkit: the holder too
    assert info.value.code == "lock-conflict"
    second = acquire(locks, "bob", break_lock=True)
    assert second["id"] == "lock_2" and (stats.locks_broken, stats.locks_acquired, stats.locks_held) == (1, 2, 1)
    for cmd in ("lock_extend", "lock_release"):
        with pytest.raises(IpcError) as info:
            run(locks, cmd, collection="apps", entity_id="a", owner="alice", lock_id="lock_2", lock_expiration=5)
        assert info.value.code == "lock-not-owner"
        with pytest.raises(IpcError) as info:
            run(locks, cmd, collection="apps", entity_id="a", owner="bob", lock_id="lock_1", lock_expiration=5)
        assert info.value.code == "lock-not-found"
    assert run(locks, "lock_release", collection="apps", entity_id="a", owner="bob", lock_id="lock_2") == {}
    assert run(locks, "lock_list")["items"] == [] and stats.locks_released == 1


def test_expiry_runs_on_the_monotonic_clock_and_is_counted(tmp_path):
    clock = Clock()
    locks, stats = table(tmp_path, clock)
    acquire(locks, "alice", lock_expiration=10)
    clock.now += 9.9
    assert len(run(locks, "lock_list")["items"]) == 1
    run(locks, "lock_extend", collection="apps", entity_id="a", owner="alice", lock_id="lock_1", lock_expiration=10)
    clock.now += 9.9
    assert run(locks, "lock_list")["items"][0]["expires_in"] == pytest.approx(0.1)
    clock.now += 0.2
    assert run(locks, "lock_list")["items"] == []   # gone for readers at once
    locks.sweep()
    assert (stats.locks_expired, stats.locks_held) == (1, 0)
    assert acquire(locks, "bob")["id"] == "lock_2"


def test_refusals_and_the_cap(tmp_path):
    locks, _ = table(tmp_path, Clock())
    for bad in ({"lock_expiration": 0}, {"lock_expiration": 601}, {"lock_expiration": True}, {"scopes": ["nope"]},
                {"scopes": "data"}, {"break_lock": "yes"}):
        with pytest.raises(IpcError) as info:
            acquire(locks, "alice", **bad)
        assert info.value.code == "bad-request", bad
    for args in ({"collection": "areas", "entity_id": "a", "owner": "x", "lock_expiration": 5},
                 {"collection": "apps", "entity_id": "", "owner": "x", "lock_expiration": 5},
                 {"collection": "apps", "entity_id": "a", "owner": "x" * 257, "lock_expiration": 5}):
        with pytest.raises(IpcError):
            run(locks, "lock_acquire", **args)
    for entity in "abc":
        acquire(locks, "alice", entity)
    with pytest.raises(IpcError) as info:
        acquire(locks, "alice", "d")
    assert info.value.code == "locks-full"


def test_a_restarted_worker_takes_the_locks_back_and_a_new_gateway_does_not(tmp_path):
    clock = Clock()
    locks, _ = table(tmp_path, clock)
    generations = Generations(str(tmp_path))
    before = generations.read("locks")
    acquire(locks, "alice", scopes=["configurations"], lock_expiration=100)
    assert generations.read("locks") != before   # announced to the HTTP workers
    clock.now += 40
    again, _ = table(tmp_path, clock, restore=True)
    items = run(again, "lock_list")["items"]
    assert [(i["id"], i["owner"], i["scopes"], i["expires_in"]) for i in items] == \
        [("lock_1", "alice", ["configurations"], 60.0)]
    assert acquire(again, "bob", "b")["id"] == "lock_2"   # ids go on
    fresh, _ = table(tmp_path, clock, restore=False)
    assert run(fresh, "lock_list")["items"] == []
    # a file of another boot (the monotonic clock started again) is not taken back
    acquire(locks, "alice", "z")
    state = json.loads((tmp_path / lockmod.FILE_NAME).read_text())
    (tmp_path / lockmod.FILE_NAME).write_text(json.dumps({**state, "boot_id": "another-boot"}))
    other, _ = table(tmp_path, clock, restore=True)
    assert run(other, "lock_list")["items"] == []
