"""rosworker/core/graph.py: change detection (fingerprint, ``generation``, ``epoch``), what its listeners
are told (the data family's pool re-checks), the cached ``graph`` snapshot, and ``node_names``.

In-process, against a fake node (``tests/support/rosunit.py``) and a listener that
records what it is told; the graph of real nodes in other processes, through a
real ROS worker, is in tests/rosworker/data/test_rosworker_pool.py and tests/test_app_e2e.py.
"""

from __future__ import annotations

import pytest

from rosworker.core import graph as graph_mod
from rosworker.core.graph import GraphMonitor, node_names
from rosworker.core.stats import Stats
from tests.support.rosunit import FakeNode

TEMP = ("/engine/temperature", "sensor_msgs/msg/Temperature")
CMD = ("/lights/cmd", "std_msgs/msg/Bool")


class RecordingPool:
    def __init__(self):
        self.checks: list[bool] = []

    def check_graph(self, full: bool) -> None:
        self.checks.append(full)


@pytest.fixture
def node():
    n = FakeNode()
    n.add("/engine/temp_sensor", pub=[TEMP])
    n.add("/lights/controller", sub=[CMD])
    return n


@pytest.fixture
def monitor(node):
    pool = RecordingPool()
    stats = Stats(pool_cap=1, cold_wait_cap=1, watchdog_threshold_ms=1000)
    graph = GraphMonitor(node, stats)      # as the core builds it
    graph.on_change(pool.check_graph)      # as the data family listens to it
    graph.pool = pool
    return graph


def test_the_first_poll_is_a_change_and_later_polls_of_the_same_graph_are_not(monitor, node):
    start = monitor.generation
    monitor.tick()
    assert monitor.generation == start + 1
    assert monitor.stats.graph_events_received == 1
    assert monitor.nodes == ["/engine/temp_sensor", "/lights/controller"]  # our own node left out
    assert monitor.topics == frozenset({TEMP[0], CMD[0]})
    assert monitor.pool.checks == [True]  # a change: every pooled entry is re-checked
    epoch = monitor.epoch
    for _ in range(3):
        monitor.tick()
    assert monitor.generation == start + 1 and monitor.stats.graph_events_received == 1
    assert monitor.epoch == epoch                   # within FULL_CHECK_EVERY of the last full check
    assert monitor.pool.checks == [True, False, False, False]


def test_a_new_topic_a_new_node_or_a_node_leaving_bumps_the_generation(monitor, node):
    monitor.tick()
    for change in (lambda: node.add("/chassis/brakes", pub=[("/chassis/pressure", "std_msgs/msg/Float32")]),
                   lambda: node.add("/idle/watcher"),                      # a node without topics
                   lambda: node.remove("/engine/temp_sensor")):
        before, epoch = monitor.generation, monitor.epoch
        change()
        monitor.tick()
        assert monitor.generation == before + 1
        assert monitor.epoch == epoch + 1
        assert monitor.pool.checks[-1] is True
    assert monitor.nodes == ["/chassis/brakes", "/idle/watcher", "/lights/controller"]
    assert TEMP[0] not in monitor.topics and "/chassis/pressure" in monitor.topics
    assert monitor.stats.graph_events_received == 4


def test_a_full_re_check_comes_every_full_check_period_without_a_change(monitor, monkeypatch):
    monitor.tick()
    generation, epoch = monitor.generation, monitor.epoch
    monkeypatch.setattr(graph_mod, "FULL_CHECK_EVERY", 0.0)  # the period has passed at every tick
    monitor.tick()
    monitor.tick()
    assert monitor.epoch == epoch + 2
    assert monitor.generation == generation  # nothing changed: no new generation
    assert monitor.pool.checks[-2:] == [True, True]


def test_the_snapshot_is_built_once_per_generation(monitor, node):
    monitor.tick()
    first = monitor.snapshot()
    calls = node.per_node_calls
    assert calls == 2 * len(node.nodes)  # publishers and subscribers of each node, our own included
    assert first["generation"] == monitor.generation and first["unchanged"] is False
    assert "complete" not in first
    assert monitor.snapshot() is first and node.per_node_calls == calls  # cached
    assert monitor.snapshot(since=monitor.generation) == {"generation": monitor.generation, "unchanged": True}
    assert monitor.snapshot(since=monitor.generation - 1) is first
    node.add("/lights/controller", pub=[("/lights/state", "std_msgs/msg/Bool")], sub=[CMD])
    monitor.tick()
    second = monitor.snapshot()
    assert second is not first and node.per_node_calls > calls
    assert second["generation"] == monitor.generation == first["generation"] + 1
    assert monitor.snapshot(since=first["generation"])["unchanged"] is False


def test_the_snapshot_lists_other_nodes_and_counts_endpoints_without_our_own(monitor, node):
    # The gateway's own node subscribes to the temperature (the pool) and publishes the command.
    node.add("/gw_sub", pub=[CMD], sub=[TEMP])
    node.add("/own_only", pub=[])  # another node; a topic below has only our own endpoints
    node.endpoints[("gw_sub", "/")]["sub"].append(("/only/ours", "std_msgs/msg/String"))
    monitor.tick()
    snap = monitor.snapshot()
    # by namespace, then name; our own node is not one of them
    assert [n["fqn"] for n in snap["nodes"]] == ["/own_only", "/engine/temp_sensor", "/lights/controller"]
    by_fqn = {n["fqn"]: n for n in snap["nodes"]}
    assert by_fqn["/engine/temp_sensor"] == {"name": "temp_sensor", "namespace": "/engine",
                                             "fqn": "/engine/temp_sensor", "publishes": [list(TEMP)],
                                             "subscribes": []}
    assert by_fqn["/lights/controller"]["subscribes"] == [list(CMD)]
    topics = {t["name"]: t for t in snap["topics"]}
    assert "/only/ours" not in topics  # nobody but the gateway on it
    assert topics[TEMP[0]] == {"name": TEMP[0], "types": [TEMP[1]], "publisher_count": 1, "subscriber_count": 0}
    assert topics[CMD[0]] == {"name": CMD[0], "types": [CMD[1]], "publisher_count": 0, "subscriber_count": 1}


def test_an_incomplete_snapshot_lists_the_node_and_is_not_kept(monitor, node):
    node.failing.add(("temp_sensor", "/engine"))  # it left between the listing and the detail
    monitor.tick()
    snap = monitor.snapshot()
    listed = {n["fqn"]: n for n in snap["nodes"]}
    assert listed["/engine/temp_sensor"]["publishes"] == []  # listed (never a 404 for a running app)
    assert "complete" not in snap
    calls = node.per_node_calls
    again = monitor.snapshot()  # asked again: rebuilt, not the incomplete one
    assert again is not snap and node.per_node_calls > calls
    node.failing.clear()
    whole = monitor.snapshot()
    assert {n["fqn"]: n for n in whole["nodes"]}["/engine/temp_sensor"]["publishes"] == [list(TEMP)]
    assert monitor.snapshot() is whole  # complete: kept


def test_a_detail_only_change_bumps_the_generation_while_somebody_asks_for_the_graph(monitor, node, monkeypatch):
    """A node subscribing to an existing topic changes no name or type: only the detail shows it."""
    monkeypatch.setattr(graph_mod, "FULL_CHECK_EVERY", 0.0)
    monitor.tick()
    first = monitor.snapshot()
    node.add("/engine/temp_sensor", pub=[TEMP], sub=[CMD])  # CMD already exists: same names and types
    generation = monitor.generation
    monitor.tick()
    assert monitor.generation == generation + 1
    fresh = monitor.snapshot()
    assert fresh is not first and fresh["generation"] == monitor.generation
    assert {n["fqn"]: n for n in fresh["nodes"]}["/engine/temp_sensor"]["subscribes"] == [list(CMD)]
    monitor.tick()  # nothing more changed: the same generation
    assert monitor.generation == generation + 1


def test_no_detail_is_read_while_nobody_asks_for_the_graph(monitor, node, monkeypatch):
    monkeypatch.setattr(graph_mod, "FULL_CHECK_EVERY", 0.0)
    monitor.tick()
    calls = node.per_node_calls
    node.add("/engine/temp_sensor", pub=[TEMP], sub=[CMD])
    for _ in range(3):
        monitor.tick()
    assert node.per_node_calls == calls == 0  # the expensive per-node calls only for a graph request


@pytest.mark.parametrize(("nodes", "expected"), [
    ([("a", "/"), ("b", "/ns"), ("c", "/ns/deep/")], ["/a", "/ns/b", "/ns/deep/c"]),
    ([("gw_sub", "/"), ("gw_sub", "/other")], ["/other/gw_sub"]),  # only our own (name, namespace)
    ([("z", "/"), ("a", "/z"), ("m", "/")], ["/m", "/z", "/z/a"]),
    ([], []),
])
def test_node_names(nodes, expected):
    assert node_names(nodes, ("gw_sub", "/")) == expected
