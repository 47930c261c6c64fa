"""rosworker/operations/feed.py, the ``execution`` sampler, with its collaborators faked.

The same behaviour through the real gateway and action server is tests/system/subscriptions/test_feeds.py; this pins
what a real run hits only by chance (a goal forgotten under a stream), and what a subscription's target
may be at all (rosworker/subscriptions/registry.py, the core's samplers).
"""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from ipc.errors import IpcError
from rosworker.core.samplers import SamplerRegistry
from rosworker.operations import feed as feed_mod
from rosworker.operations.feed import ExecutionFeed
from rosworker.subscriptions.registry import _target
from tests.support.rosunit import FakeEvents, TimerExecutor, feed_subscription


@pytest.fixture
def world():
    executor, events, goals, ended = TimerExecutor(), FakeEvents(), {}, []

    def get(goal_id):
        if goal_id not in goals:
            raise IpcError("no-such-execution", "Execution not found", {"execution_id": goal_id})
        return goals[goal_id]

    feed = ExecutionFeed(SimpleNamespace(executor=executor, events=events), SimpleNamespace(get=get))

    def watch(s):
        def end():
            ended.append(s.id)
            feed.unwatch(s)   # as the registry does: the subscription goes
        feed.watch(s, end)

    return SimpleNamespace(executor=executor, events=events, goals=goals, feed=feed, ended=ended, watch=watch)


def test_a_finished_goal_repeats_its_last_frame_then_ends(world, monkeypatch):
    goal = SimpleNamespace(done=False, wire=lambda: {"id": "g", "status": "running"})
    world.goals["g"] = goal
    s = feed_subscription("execution", {"goal": "g", "operation_id": "fib"})
    world.feed.check(s)
    world.watch(s)
    world.executor.fire()
    assert "last" not in world.events.frames[-1][1]
    goal.done = True
    monkeypatch.setattr(feed_mod, "FINISHED_LINGER", 0.0)
    world.executor.fire()
    assert world.events.frames[-1][1]["last"] is True and world.ended == []
    world.executor.fire()
    assert world.events.frames[-1][1]["last"] is True and world.ended == [s.id]
    assert [t for t in world.executor.timers if not t.cancelled] == []  # no tick after the end


def test_a_goal_forgotten_under_its_stream_ends_it_with_an_error(world):
    world.goals["g"] = SimpleNamespace(done=False, wire=lambda: {"id": "g"})
    s = feed_subscription("execution", {"goal": "g"})
    world.watch(s)
    del world.goals["g"]
    world.executor.fire()
    meta = world.events.frames[-1][1]
    assert meta["last"] is True and meta["error"]["code"] == "no-such-execution"
    assert world.ended == [s.id]


@pytest.mark.parametrize("target,code", [({"goal": "nope"}, "no-such-execution"), ({}, "bad-request")])
def test_check_refuses_an_execution_it_cannot_follow(world, target, code):
    with pytest.raises(IpcError) as info:
        world.feed.check(feed_subscription("execution", target))
    assert info.value.code == code


@pytest.mark.parametrize("target", [{"node": "/t", "name": "x", "id": "x" * 5000}, {str(i): "x" for i in range(9)},
                                    {"a": 1}, ["goal"]])
def test_a_target_is_a_few_short_strings_whatever_the_kind(target):
    with pytest.raises(IpcError) as info:
        _target(target)
    assert info.value.code == "bad-request"


def test_a_kind_no_family_streams_is_refused():
    samplers = SamplerRegistry()
    samplers.register("execution", object())
    with pytest.raises(IpcError) as info:
        samplers.get("topic")
    assert info.value.code == "bad-request" and "'execution'" in info.value.message
