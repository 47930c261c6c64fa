"""The fleet gateway's robots table and its fault events (supervisor/fleet/robots.py)."""

from __future__ import annotations

import time

from supervisor.fleet.robots import FaultEvents, Robots, attributed


def test_the_table_is_bounded_the_longest_away_makes_room_and_past_that_a_newcomer_is_refused():
    robots = Robots(max_robots=3, forget_after=0)
    for name in ("a", "b", "c"):
        assert robots.came(name) is not None
    assert robots.came("d") is None and robots.refused == 1
    robots.went("b")
    time.sleep(0.01)
    robots.went("a")
    assert robots.came("d") is not None            # b, away the longest, made room
    assert sorted(robots.by_name) == ["a", "c", "d"]
    assert robots.came("a").online and robots.get("a").order == 1   # back: the same robot, the same order
    assert robots.came("e") is None and robots.refused == 2


def test_robots_away_past_forget_after_are_forgotten():
    robots = Robots(max_robots=10, forget_after=0.05)
    robots.came("a")
    robots.came("b")
    robots.went("a")
    assert robots.forget_old() == []
    time.sleep(0.06)
    assert robots.forget_old() == ["a"] and sorted(robots.by_name) == ["b"]
    assert Robots(10, 0).forget_old() == []


def test_per_robot_counts_and_smoothed_latency():
    robots = Robots(10, 0)
    a = robots.came("a")
    a.answered(0.010)
    a.answered(0.020)
    assert round(a.latency_ms, 3) == 13.0
    robots.came("b")
    robots.went("b")
    maps = robots.per_robot()
    assert maps["robot_up"] == {"a": 1, "b": 0}
    assert maps["robot_latency_ms"] == {"a": a.latency_ms}
    status = a.status()
    assert status["name"] == "a" and status["status"] == "online" and status["url"] == "zenoh:sovd/a"


def test_fault_events_get_growing_fleet_ids_name_their_robot_and_are_kept_bounded():
    events = FaultEvents(keep=3)
    start = events.next_id
    assert abs(start / 1e6 - time.time()) < 5                 # µs since the epoch: grows across restarts
    taken = [events.take("r", {"id": i, "event_type": "fault_confirmed", "fault": {"fault_code": f"C{i}"},
                               "timestamp": 1.0}) for i in range(5)]
    assert [t["id"] for t in taken] == list(range(start + 1, start + 6))
    assert taken[0]["fault"]["x-medkit"] == {"contributors": ["peer:r"]}
    assert [e["fault"]["fault_code"] for e in events.after(0)] == ["C2", "C3", "C4"]
    assert [e["id"] for e in events.after(taken[3]["id"])] == [taken[4]["id"]]


def test_attribution_keeps_what_the_item_had():
    item = {"id": "x", "x-medkit": {"member_ids": ["m"]}}
    out = attributed(item, "r")
    assert out["x-medkit"] == {"member_ids": ["m"], "contributors": ["peer:r"]}
    assert item["x-medkit"] == {"member_ids": ["m"]}           # not changed in place
    assert attributed({"x-medkit": "odd"}, "r")["x-medkit"] == {"contributors": ["peer:r"]}
