"""``GET /metrics`` of one app against a stand-in ROS worker: real output parsed by prometheus_client.

The HTTP metrics here are this process's own (no ``PROMETHEUS_MULTIPROC_DIR``:
the sums over gunicorn's workers are checked through a real gateway in
``tests/system/fleet/test_fleet_e2e.py``), so the checks compare values before and after.
"""

from __future__ import annotations

import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from prometheus_client.parser import text_string_to_metric_families

from app.core import metrics
from tests.support.fakeworker import ROBOT, FakeWorker, data_sample, make_app

TOPIC = "/powertrain/engine/temperature"


def scrape(client) -> dict:
    """``{family name: family}`` of one real scrape; the samples of a family by (name, labels)."""
    r = client.get("/metrics")
    assert r.status_code == 200
    assert r.headers["Content-Type"].startswith("text/plain")
    return {f.name: f for f in text_string_to_metric_families(r.get_data(as_text=True))}


def value(families: dict, family: str, sample: str | None = None, **labels) -> float | None:
    fam = families.get(family)
    if fam is None:
        return None
    for s in fam.samples:
        if s.name == (sample or family) and all(s.labels.get(k) == v for k, v in labels.items()):
            return s.value
    return None


def note_series(c) -> None:
    # The counters are the process's: a test module that ran before in this process (another
    # app, with routes of its own) may have left series; the storm may add none of its own.
    c.series_before = {(s.labels["route"], s.labels["method"], s.labels["status"])
                       for s in scrape(c)["sovd_http_requests"].samples
                       if s.name == "sovd_http_requests_total"}


pytestmark = pytest.mark.fakeworker(
    scope="module", client_scope="module", on_client=note_series,
    samples={TOPIC: data_sample(TOPIC, "sensor_msgs/msg/Temperature", {"temperature": 93.5})},
    stats={"details": {"evictions": {"lru": 3, "idle": 1}, "commands": {"sample": {"count": 7, "time_us": 700}},
                       "ticks": {"fast": 5}, "publishers": 2},
           "streams": {"active_subscriptions": 2, "max_subscriptions": 1000, "subscriptions_created": 4,
                       "frames_published": 40}})


def test_requests_and_latency_count_by_route_template(client):
    before = scrape(client)
    route = "/api/v1/<collection:collection>/<entity_id>/data/<data_id:data_id>"
    for _ in range(3):
        assert client.get(f"/api/v1/apps/temp_sensor/data{TOPIC}").status_code == 200
    assert client.get("/api/v1/apps/nope").status_code == 404
    assert client.get("/no/such/route").status_code == 404
    after = scrape(client)
    family = "sovd_http_requests"
    delta = (value(after, family, "sovd_http_requests_total", route=route, method="GET", status="200") or 0) \
        - (value(before, family, "sovd_http_requests_total", route=route, method="GET", status="200") or 0)
    assert delta == 3
    assert value(after, family, "sovd_http_requests_total", route="/api/v1/<collection:collection>/<entity_id>",
                 method="GET", status="404") >= 1
    assert value(after, family, "sovd_http_requests_total", route="unmatched", method="GET", status="404") >= 1
    hist = "sovd_http_request_duration_seconds"
    assert after[hist].type == "histogram"
    count = value(after, hist, hist + "_count", route=route)
    assert count - (value(before, hist, hist + "_count", route=route) or 0) == 3
    # Buckets resolve 0.25 ms to 5 s, and every observation is in the +Inf bucket.
    les = {s.labels["le"] for s in after[hist].samples if s.name == hist + "_bucket" and s.labels["route"] == route}
    assert {"0.00025", "5.0", "+Inf"} <= les
    assert value(after, hist, hist + "_bucket", route=route, le="+Inf") == count


def test_the_ros_worker_counters_with_names_types_and_help(client):
    families = scrape(client)
    assert value(families, "sovd_ros_worker_up") == 1.0
    expected = {  # family -> (type, value in the fake worker's stats)
        "sovd_ros_pool_size": ("gauge", 1), "sovd_ros_pool_cap": ("gauge", 256),
        "sovd_ros_pool_hits": ("counter", 5), "sovd_ros_pool_misses": ("counter", 2),
        "sovd_ros_cold_waits": ("gauge", 0), "sovd_ros_cold_wait_cap": ("gauge", 4),
        "sovd_ros_queue_depth": ("gauge", 0), "sovd_ros_queue_depth_max": ("gauge", 2),
        "sovd_ros_watchdog_trips": ("counter", 0), "sovd_ros_pool_bytes": ("gauge", 2048),
        "sovd_ros_max_task_seconds": ("gauge", 900e-6), "sovd_ros_subscriptions": ("gauge", 2),
        "sovd_ros_subscriptions_created": ("counter", 4), "sovd_ros_publishers": ("gauge", 2),
    }
    for name, (kind, want) in expected.items():
        fam = families[name]
        assert fam.type == kind, name
        assert fam.documentation, name
        sample = name + "_total" if kind == "counter" else name
        assert value(families, name, sample) == pytest.approx(want), name
    assert value(families, "sovd_ros_tasks", "sovd_ros_tasks_total", outcome="completed") == 9
    assert value(families, "sovd_ros_pool_evictions", "sovd_ros_pool_evictions_total", cause="lru") == 3
    assert value(families, "sovd_ros_commands", "sovd_ros_commands_total", command="sample") == 7
    assert value(families, "sovd_ros_command_seconds", "sovd_ros_command_seconds_total",
                 command="sample") == pytest.approx(700e-6)
    # Every family is in the sovd_ namespace.
    assert all(name.startswith("sovd_") for name in families)


def test_metrics_and_health_are_outside_the_api_and_count_like_any_route(client):
    before = scrape(client)
    client.get("/metrics")
    after = scrape(client)
    key = {"route": "/metrics", "method": "GET", "status": "200"}
    assert (value(after, "sovd_http_requests", "sovd_http_requests_total", **key) or 0) \
        > (value(before, "sovd_http_requests", "sovd_http_requests_total", **key) or 0)
    assert client.get("/api/v1/metrics").status_code == 404


def test_a_scrape_while_the_ros_worker_is_down_says_so_within_the_ipc_timeout():
    with FakeWorker() as fw:
        fw.set_graph(list(ROBOT))
        client = make_app(fw, ipc_timeout=0.2).test_client()
        assert value(scrape(client), "sovd_ros_worker_up") == 1.0
        fw.silent.add("stats")  # alive but not answering
        started = time.monotonic()
        families = scrape(client)
        took = time.monotonic() - started
        assert value(families, "sovd_ros_worker_up") == 0.0
        assert "sovd_ros_pool_size" not in families  # no stale counters while it is away
        assert "sovd_http_requests" in families      # the HTTP side answers all the same
        assert took < 0.2 + 0.5, f"a scrape took {took:.2f} s with an IPC timeout of 0.2 s"
        fw.stop()  # gone altogether
        families = scrape(client)
        assert value(families, "sovd_ros_worker_up") == 0.0


SEGMENT = st.one_of(st.text(st.sampled_from(list("abcz019_-.%~")), min_size=1, max_size=12),
                    st.sampled_from(["%2F", "..", "", "x" * 40, "data", "apps", "components", "functions",
                                     "temp_sensor", "cyclic-subscriptions", "docs", "events", "health"]))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(parts=st.lists(SEGMENT, min_size=1, max_size=8),
       method=st.sampled_from(["GET", "PUT", "POST", "DELETE", "PATCH", "BREW", "OPTIONS"]))
def test_label_sets_stay_bounded_under_a_fuzzed_path_storm(client, parts, method):
    client.open("/api/v1/" + "/".join(parts), method=method)


def test_after_the_storm_only_route_templates_and_known_methods_are_labels(client):
    """Runs after the storm above (file order): ~300 distinct paths and methods were sent."""
    client.open("/api/v1/apps", method="BREW")
    families = scrape(client)
    app_rules = {rule.rule for rule in client.application.url_map.iter_rules()} | {metrics.UNMATCHED}
    routes, methods, series = set(), set(), 0
    for s in families["sovd_http_requests"].samples:
        if s.name == "sovd_http_requests_total" \
                and (s.labels["route"], s.labels["method"], s.labels["status"]) not in client.series_before:
            routes.add(s.labels["route"])
            methods.add(s.labels["method"])
            series += 1
    assert routes <= app_rules, routes - app_rules
    assert methods <= set(metrics.METHODS) | {"other"}
    assert "other" in methods  # BREW is counted, under a bounded label
    # Bounded by routes × methods × statuses seen, not by the ~300 distinct paths sent.
    assert series <= len(app_rules) * 8 * 10
    # nor does the cache of label sets grow past them
    assert len(metrics.http()._children) == series + len(client.series_before)
    assert len(routes) < 40
