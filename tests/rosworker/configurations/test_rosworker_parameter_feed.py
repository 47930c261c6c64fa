"""rosworker/configurations/feed.py, the ``parameter`` sampler, with its collaborators faked.

The same behaviour through the real gateway and parameter node is tests/system/subscriptions/test_feeds.py; this
pins the ordering rules that a real run hits only by chance (an event that overtakes a read, a deleted
parameter).
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest
from rcl_interfaces.msg import Parameter, ParameterEvent, ParameterType, ParameterValue

from ipc.errors import IpcError
from rosworker.configurations.feed import ParameterFeed
from tests.support.rosunit import FakeEvents, TimerExecutor, feed_subscription


class Params:
    """The parameter clients: the reads started, their ``done`` kept to answer them later."""

    def __init__(self):
        self.reads: list = []

    def run(self, node, gen, done):
        self.reads.append(done)


class Defaults:
    """The /parameter_events drain: the listeners the feed adds; a test calls them with its events."""

    def __init__(self):
        self.listeners = []

    def drain(self):
        pass


class Commands:
    def op_get(self, node, name):
        return (node, name)


def double(x):
    return ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=x)


@pytest.fixture
def world():
    executor, events, params, defaults = TimerExecutor(), FakeEvents(), Params(), Defaults()
    feed = ParameterFeed(SimpleNamespace(executor=executor, events=events), params, defaults, Commands())
    return SimpleNamespace(executor=executor, events=events, params=params, defaults=defaults, feed=feed)


def test_a_parameter_event_that_overtakes_the_read_wins(world):
    s = feed_subscription("parameter", {"node": "/t", "name": "ratio", "id": "ratio"})
    world.feed.watch(s, lambda: None)
    world.executor.fire()
    assert world.events.frames == []  # no value yet: no frame
    event = ParameterEvent(node="/t", changed_parameters=[Parameter(name="ratio", value=double(0.75))])
    for listener in world.defaults.listeners:
        listener(event)
    world.params.reads[0]({"name": "ratio", "value": 0.5, "type": "double", "description": "d"})
    world.executor.fire()
    key, meta, data = world.events.frames[-1]
    assert key == s.key and meta["kind"] == "parameter" and "error" not in meta
    body = json.loads(data)
    assert body["parameter"] == {"name": "ratio", "value": 0.75, "type": "double", "description": "d"}
    assert body["node"] == "/t" and body["id"] == "ratio"


def test_a_deleted_parameter_gives_error_frames_until_it_is_back(world):
    s = feed_subscription("parameter", {"node": "/t", "name": "ratio", "id": "ratio"})
    world.feed.watch(s, lambda: None)
    world.params.reads[0]({"name": "ratio", "value": 0.5, "type": "double"})
    for listener in world.defaults.listeners:
        listener(ParameterEvent(node="/t", deleted_parameters=[Parameter(name="ratio")]))
        listener(ParameterEvent(node="/other", new_parameters=[Parameter(name="ratio", value=double(9.0))]))
    world.executor.fire()
    assert world.events.frames[-1][1]["error"]["code"] == "no-such-parameter"
    for listener in world.defaults.listeners:
        listener(ParameterEvent(node="/t", new_parameters=[Parameter(name="ratio", value=double(0.25))]))
    world.executor.fire()
    assert json.loads(world.events.frames[-1][2])["parameter"]["value"] == 0.25


def test_a_stream_that_goes_leaves_no_timer_and_no_listener_behind(world):
    s = feed_subscription("parameter", {"node": "/t", "name": "ratio", "id": "ratio"})
    world.feed.watch(s, lambda: None)
    world.feed.unwatch(s)
    assert [t for t in world.executor.timers if not t.cancelled] == [] and world.feed._by_node == {}
    world.params.reads[0]({"name": "ratio", "value": 0.5, "type": "double"})   # a read that comes late
    assert world.events.frames == []


@pytest.mark.parametrize("target", [{"node": "/t", "name": "x"}, {"node": "", "name": "x", "id": "x"}])
def test_check_refuses_a_parameter_it_cannot_name(world, target):
    with pytest.raises(IpcError) as info:
        world.feed.check(feed_subscription("parameter", target))
    assert info.value.code == "bad-request"
