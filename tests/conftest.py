"""Session-wide isolation: each test session gets its own ROS domain, localhost only.

This runs before any test module imports rclpy, so every process the tests
start (they inherit the environment) lives in the same private domain.
"""

from __future__ import annotations

import os

import pytest

from common.harness.procs import private_ros_domain

private_ros_domain()


@pytest.fixture(scope="session")
def ros_domain() -> int:
    return int(os.environ["ROS_DOMAIN_ID"])


@pytest.fixture
def diag():
    """``diag(node, namespace="/", rate=10)``: a real ``/diagnostics`` publisher (common/harness/diagpub.py), once the
    gateway's subscription has matched it (no report is lost to discovery); stopped after the test."""
    from common.harness.diagpub import DiagPub

    started: list[DiagPub] = []

    def make(node: str, namespace: str = "/", rate: float = 10) -> DiagPub:
        pub = DiagPub(node, namespace, rate)
        started.append(pub)
        return pub.matched()

    yield make
    for pub in started:
        pub.stop()


@pytest.fixture(scope="module")
def gateway():
    """``gateway(*flags, exit_code=None, **options)``: a real gateway (common.harness.gateway.Gateway) started
    with those flags and options (``env``, ``timeout`` ...), once a module: the same flags again give the same
    gateway.  Every gateway it started is stopped at the module's end (in reverse), and one given an
    ``exit_code`` must exit with it.  A module's ``gw`` fixture asks for its own: ``gateway("--allow-publish")``
    (after the fixtures of the nodes it must see, so that those start first)."""
    from common.harness.gateway import Gateway

    started: dict[str, tuple[Gateway, int | None]] = {}  # repr((flags, options)) -> (gateway, exit code)

    def make(*flags: str, exit_code: int | None = None, **options) -> Gateway:
        key = repr((flags, sorted(options.items())))
        if key not in started:
            started[key] = (Gateway(*flags, **options), exit_code)
        return started[key][0]

    yield make
    codes = {key: (gw.stop(), exit_code) for key, (gw, exit_code) in reversed(started.items())}
    wrong = {key: code for key, (code, expected) in codes.items() if expected is not None and code != expected}
    assert not wrong, f"gateways that exited with another code than expected: {wrong}"


@pytest.fixture
def nodes():
    """ROS nodes (``RosNode``/``publisher``) appended here are stopped at the end of the test."""
    started: list = []
    yield started
    for node in reversed(started):
        node.stop()


# ---------------------------------------------------------------- the HTTP app on a fake ROS worker
#
# ``fw`` is a FakeWorker (tests/support/fakeworker.py) holding the ROBOT graph, ``client`` a Flask
# test client of ``make_app(fw)``. A module says what it needs with one marker:
#
#     pytestmark = pytest.mark.fakeworker(scope="module", allow_publish=True)
#
#   scope         "function" (default): a fresh worker for every test; "module": one worker for
#                 the module. A function-scoped client over a module's worker starts clean: no
#                 subscriptions, no canned errors, no requests recorded.
#   client_scope  "function" (default) or "module" (one client, over a module-scoped worker)
#   samples, type_infos, stats
#                 put into the worker before its first test (``stats`` updates the canned
#                 sections, so it can add or replace one)
#   on_client     called with a new client once it is made (a module noting what it saw first)
#   anything else goes to ``make_app`` (allow_publish, cors_origins, sample_timeout, ...)

_SPEC_KEYS = ("scope", "client_scope", "samples", "type_infos", "stats", "on_client")


def pytest_configure(config):
    config.addinivalue_line("markers", "fakeworker(scope, client_scope, samples, type_infos, stats, on_client, "
                                       "**make_app options): the fw and client fixtures of tests/conftest.py")


def _fakeworker_spec(request) -> tuple[dict, dict]:
    """(this module's fixture settings, the make_app options) from its ``fakeworker`` marker."""
    marker = request.node.get_closest_marker("fakeworker")
    kwargs = dict(marker.kwargs) if marker else {}
    spec = {"scope": "function", "client_scope": "function", "samples": {}, "type_infos": {},
            "stats": {}, "on_client": None}
    spec.update({k: kwargs.pop(k) for k in _SPEC_KEYS if k in kwargs})
    if spec["client_scope"] == "module" and spec["scope"] != "module":
        raise pytest.UsageError("fakeworker: a module-scoped client needs a module-scoped worker")
    return spec, kwargs


def _robot_worker(spec: dict):
    from tests.support.fakeworker import ROBOT, FakeWorker

    worker = FakeWorker()
    worker.set_graph(list(ROBOT))
    worker.samples.update(spec["samples"])
    worker.type_infos.update(spec["type_infos"])
    worker.stats.update(spec["stats"])
    return worker


def _test_client(worker, spec: dict, options: dict):
    from tests.support.fakeworker import make_app

    client = make_app(worker, **options).test_client()
    if spec["on_client"] is not None:
        spec["on_client"](client)
    return client


@pytest.fixture(scope="module")
def _module_fw(request):
    spec, _ = _fakeworker_spec(request)
    with _robot_worker(spec) as worker:
        yield worker


@pytest.fixture
def fw(request):
    """The fake ROS worker with the ROBOT graph (see the ``fakeworker`` marker above)."""
    spec, _ = _fakeworker_spec(request)
    if spec["scope"] == "module":
        yield request.getfixturevalue("_module_fw")
        return
    with _robot_worker(spec) as worker:
        yield worker


@pytest.fixture(scope="module")
def _module_client(request, _module_fw):
    spec, options = _fakeworker_spec(request)
    return _test_client(_module_fw, spec, options)


@pytest.fixture
def client(request, fw):
    """A Flask test client of ``make_app(fw, **options)`` (see the ``fakeworker`` marker above)."""
    spec, options = _fakeworker_spec(request)
    if spec["client_scope"] == "module":
        return request.getfixturevalue("_module_client")
    if spec["scope"] == "module":  # the worker outlives the test: start from a clean one
        fw.subscriptions.clear()
        fw.errors.clear()
        with fw._lock:
            fw.requests.clear()
    return _test_client(fw, spec, options)
