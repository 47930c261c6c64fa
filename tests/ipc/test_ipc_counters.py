"""The counter declaration (``ipc/counters.py``) against the five places that show counters.

The ROS worker's ``stats`` answer (the real ``rosworker/core/stats.py``), ``/health`` and ``/metrics``
(the real Flask app against a stand-in ROS worker that answers with that real snapshot), the
OpenAPI ``HealthStatus`` schema and ``ipc/PROTOCOL.md``: each must show exactly the declared
counters, in the declared order, so a counter added, renamed or dropped anywhere but in the
declaration fails here.  (Through a real gateway: ``tests/system/subscriptions/test_app_streams.py`` checks the HTTP
workers' stream counters in ``/health`` against ``/metrics``.)
"""

from __future__ import annotations

import tempfile
from collections import Counter as Tally

import pytest
from prometheus_client.parser import text_string_to_metric_families

from app import openapi
from common.settings import SETTINGS
from ipc import counters
from rosworker.core.stats import Stats
from tests.support.fakeworker import FakeWorker, make_app

HEALTH_SECTIONS = [name for name, health in counters.SECTIONS.items() if health]


def _busy_stats() -> Stats:
    """Real stats with every kind of value present (a command timed, a tick, an eviction)."""
    stats = Stats(pool_cap=8, cold_wait_cap=3, watchdog_threshold_ms=1000)
    stats.task_finished(stats.task_started(), True, "sample")
    stats.evictions["lru"] += 1
    stats.ticks["fast"] = 4
    stats.pool_hits = 5
    return stats


@pytest.fixture
def fw():
    worker = FakeWorker().start()
    worker.stats = _busy_stats().snapshot()
    yield worker
    worker.stop()


def test_the_declaration_is_well_formed():
    keys = Tally((c.section, c.name) for c in counters.COUNTERS)
    assert [k for k, n in keys.items() if n > 1] == []
    kinds = {counters.COUNTER, counters.GAUGE, counters.FLAG, counters.BY, counters.TIMINGS, counters.GAUGES_BY}
    origins = (counters.ROS, counters.HTTP, counters.FLEET)
    setting_names = {s.name for s in SETTINGS}
    for c in counters.COUNTERS:
        assert c.section in counters.ALL_SECTIONS and c.kind in kinds and c.origin in origins, c
        assert (c.origin == counters.FLEET) == (c.section in counters.FLEET_SECTIONS), c
        assert c.help and (c.metric is None or c.metric.startswith("sovd_")), c
        assert c.setting is None or c.setting in setting_names, c
        assert (c.kind in (counters.BY, counters.TIMINGS, counters.GAUGES_BY)) <= bool(c.label and c.metric), c
        assert c.label is None or c.kind != counters.COUNTER or c.metric in counters.FAMILY_HELP, c
    # A metric belongs to one counter, unless it is a labelled family of several.
    metrics = Tally(c.metric for c in counters.COUNTERS if c.metric)
    assert [m for m, n in metrics.items() if n > 1 and m not in counters.FAMILY_HELP] == []
    # The HTTP workers' counters are /health's only (the ROS worker neither counts nor sends them).
    assert all(c.section in HEALTH_SECTIONS for c in counters.HTTP_COUNTERS)


def test_the_ros_workers_stats_answer_is_the_declared_counters_in_order():
    snapshot = _busy_stats().snapshot()
    assert list(snapshot) == list(counters.SECTIONS)
    for name in counters.SECTIONS:
        assert list(snapshot[name]) == [c.name for c in counters.section(name, counters.ROS)], name
    assert snapshot["details"]["commands"]["sample"]["count"] == 1
    assert snapshot["details"]["evictions"] == {**dict.fromkeys(counters.EVICTION_CAUSES, 0), "lru": 1}


def _health_keys(name: str) -> list[str]:
    return list(counters.health_keys(name)) + (["evictions"] if name == "data_provider" else [])


def test_health_shows_the_declared_counters_with_and_without_an_answer(fw):
    with tempfile.TemporaryDirectory() as nobody:  # no ROS worker there: the defaults
        down = make_app(runtime_dir=nobody, max_pool_size=99, max_subscriptions=7).test_client()
        alone = down.get("/api/v1/health").get_json()
    up = make_app(fw).test_client().get("/api/v1/health").get_json()
    for body in (alone, up):
        for name in HEALTH_SECTIONS:
            assert list(body[counters.SECTIONS[name]]) == _health_keys(name), name
    # Before any answer: zeros, false, and what the settings say.
    assert alone["x-medkit-data-provider"]["pool_cap"] == 99 and alone["x-medkit-streams"]["max_subscriptions"] == 7
    assert alone["x-medkit-subscription-executor"]["worker_alive"] is False
    assert up["x-medkit-data-provider"]["pool_hits"] == 5 and up["x-medkit-data-provider"]["pool_cap"] == 8


def test_the_openapi_health_schema_is_the_declared_counters():
    health = openapi.document()["components"]["schemas"]["HealthStatus"]["properties"]
    for name in HEALTH_SECTIONS:
        schema = health[counters.SECTIONS[name]]
        assert schema["required"] == _health_keys(name), name
        assert list(schema["properties"]) == _health_keys(name), name
        for c in counters.section(name):
            assert schema["properties"][c.name]["type"] == ("boolean" if c.kind == counters.FLAG else "integer")


def test_a_scrape_exports_every_declared_ros_metric_with_its_kind_and_help(fw):
    text = make_app(fw).test_client().get("/metrics").get_data(as_text=True)
    families = {f.name: f for f in text_string_to_metric_families(text)}
    ros = {name: f for name, f in families.items() if name.startswith("sovd_ros_") and name != "sovd_ros_worker_up"}
    declared = {c.metric for c in counters.ROS_COUNTERS if c.metric}
    declared |= {seconds for seconds, _help in counters.TIMINGS_SECONDS.values()}
    assert set(ros) == declared
    for c in counters.ROS_COUNTERS:
        if c.metric is None:
            continue
        family = families[c.metric]
        assert family.type == ("counter" if c.kind in (counters.COUNTER, counters.BY, counters.TIMINGS) else "gauge")
        assert family.documentation == counters.FAMILY_HELP.get(c.metric, c.help)
    for c in counters.HTTP_COUNTERS:  # the HTTP workers' own metrics carry the declared help too
        assert families[c.metric].documentation == c.help
    assert [s.value for s in families["sovd_ros_pool_hits"].samples if s.name == "sovd_ros_pool_hits_total"] == [5]


def test_protocol_md_holds_the_generated_table():
    documented = counters.documented(counters.PROTOCOL.read_text())
    assert documented is not None, "ipc/PROTOCOL.md lost its counters block"
    assert documented == counters.markdown(), \
        "ipc/PROTOCOL.md's counter table is stale: run `python -m ipc.counters --write`"
    for c in counters.COUNTERS:
        assert f"| `{c.name}` |" in documented
