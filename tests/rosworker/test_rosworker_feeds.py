"""rosworker/configurations/feed.py with its collaborators faked: the frames of an execution's and a parameter's feed.

The same behaviour through the real gateway, action server and parameter node is
tests/system/test_feeds.py; this pins the ordering rules that a real run hits only by chance
(an event that overtakes a read, a deleted parameter, a goal forgotten under a stream).
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest
from rcl_interfaces.msg import Parameter, ParameterEvent, ParameterType, ParameterValue

from ipc.errors import IpcError
from rosworker.configurations import feed as feeds_mod
from rosworker.configurations.feed import Feeds
from rosworker.core.executor import Timer
from rosworker.subscriptions.registry import Subscription


class Executor:
    def __init__(self):
        self.timers: list[Timer] = []

    def call_later(self, delay, fn):
        timer = Timer(delay, fn)
        self.timers.append(timer)
        return timer

    def guarded(self, _where, fn, *args):
        return fn(*args)

    def fire(self):
        """Run the one live timer (a feed keeps exactly one armed)."""
        live = [t for t in self.timers if not t.cancelled]
        self.timers = []
        assert len(live) == 1, live
        live[0].fn()


class Registry:
    def __init__(self):
        self.frames: list[tuple[bytes, dict, bytes]] = []
        self.ended: list[str] = []

    def publish(self, key, meta, data=b"{}"):
        self.frames.append((key, meta, data))

    def end(self, sub):
        self.ended.append(sub.id)
        feeds.unwatch(sub)


class Params:
    def __init__(self):
        self.listeners = []
        self.reads: list = []

    def drain_events(self):
        pass

    def op_get(self, node, name):
        return (node, name)

    def run(self, node, gen, done):
        self.reads.append(done)


def sub(kind, target, interval="fast"):
    return Subscription(id="sub_0123456789abcdef", collection="apps", entity_id="tuner", resource="/r",
                        topic="", bytes="array", interval=interval, duration=60, created_at_ns=0, kind=kind,
                        target=target)


def double(x):
    return ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=x)


feeds: Feeds


@pytest.fixture
def world():
    global feeds
    executor, registry, params = Executor(), Registry(), Params()
    goals = {}

    def get(goal_id):
        if goal_id not in goals:
            raise IpcError("no-such-execution", "Execution not found", {"execution_id": goal_id})
        return goals[goal_id]

    feeds = Feeds(registry, executor, SimpleNamespace(get=get), params)
    return SimpleNamespace(executor=executor, registry=registry, params=params, goals=goals)


def test_a_parameter_event_that_overtakes_the_read_wins(world):
    s = sub("parameter", {"node": "/t", "name": "ratio", "id": "ratio"})
    feeds.watch(s)
    world.executor.fire()
    assert world.registry.frames == []  # no value yet: no frame
    event = ParameterEvent(node="/t", changed_parameters=[Parameter(name="ratio", value=double(0.75))])
    for listener in world.params.listeners:
        listener(event)
    world.params.reads[0]({"name": "ratio", "value": 0.5, "type": "double", "description": "d"})
    world.executor.fire()
    key, meta, data = world.registry.frames[-1]
    assert key == s.key and meta["kind"] == "parameter" and "error" not in meta
    body = json.loads(data)
    assert body["parameter"] == {"name": "ratio", "value": 0.75, "type": "double", "description": "d"}
    assert body["node"] == "/t" and body["id"] == "ratio"


def test_a_deleted_parameter_gives_error_frames_until_it_is_back(world):
    s = sub("parameter", {"node": "/t", "name": "ratio", "id": "ratio"})
    feeds.watch(s)
    world.params.reads[0]({"name": "ratio", "value": 0.5, "type": "double"})
    for listener in world.params.listeners:
        listener(ParameterEvent(node="/t", deleted_parameters=[Parameter(name="ratio")]))
        listener(ParameterEvent(node="/other", new_parameters=[Parameter(name="ratio", value=double(9.0))]))
    world.executor.fire()
    assert world.registry.frames[-1][1]["error"]["code"] == "no-such-parameter"
    for listener in world.params.listeners:
        listener(ParameterEvent(node="/t", new_parameters=[Parameter(name="ratio", value=double(0.25))]))
    world.executor.fire()
    assert json.loads(world.registry.frames[-1][2])["parameter"]["value"] == 0.25


def test_a_finished_goal_repeats_its_last_frame_then_ends(world, monkeypatch):
    goal = SimpleNamespace(done=False, wire=lambda: {"id": "g", "status": "running"})
    world.goals["g"] = goal
    s = sub("execution", {"goal": "g", "operation_id": "fib"})
    feeds.check(s)
    feeds.watch(s)
    world.executor.fire()
    assert "last" not in world.registry.frames[-1][1]
    goal.done = True
    monkeypatch.setattr(feeds_mod, "FINISHED_LINGER", 0.0)
    world.executor.fire()
    assert world.registry.frames[-1][1]["last"] is True and world.registry.ended == []
    world.executor.fire()
    assert world.registry.frames[-1][1]["last"] is True and world.registry.ended == [s.id]
    assert [t for t in world.executor.timers if not t.cancelled] == []  # no tick after the end


def test_a_goal_forgotten_under_its_stream_ends_it_with_an_error(world):
    world.goals["g"] = SimpleNamespace(done=False, wire=lambda: {"id": "g"})
    s = sub("execution", {"goal": "g"})
    feeds.watch(s)
    del world.goals["g"]
    world.executor.fire()
    meta = world.registry.frames[-1][1]
    assert meta["last"] is True and meta["error"]["code"] == "no-such-execution"
    assert world.registry.ended == [s.id]


@pytest.mark.parametrize("kind,target,code", [
    ("execution", {"goal": "nope"}, "no-such-execution"),
    ("execution", {}, "bad-request"),
    ("parameter", {"node": "/t", "name": "x"}, "bad-request"),
    ("parameter", {"node": "/t", "name": "x", "id": "x" * 5000}, "bad-request"),
    ("parameter", {str(i): "x" for i in range(9)}, "bad-request"),
    ("topic", {}, "bad-request"),
])
def test_check_refuses_what_it_cannot_stream(world, kind, target, code):
    with pytest.raises(IpcError) as info:
        feeds.check(sub(kind, target))
    assert info.value.code == code
