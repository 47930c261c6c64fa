"""The fleet's wire (ipc/fleet.py): keys, families, the request and reply envelopes and their checks."""

from __future__ import annotations

import msgpack
import pytest

from ipc import fleet


@pytest.mark.parametrize("path, family", [
    ("/api/v1/apps/x", "discovery"), ("/api/v1/apps", "discovery"), ("/api/v1/functions/f/hosts", "discovery"),
    ("/api/v1/apps/x/data/a/b", "data"), ("/api/v1/components/h/data-categories", "data"),
    ("/api/v1/apps/x/faults/CODE", "faults"), ("/api/v1/faults", "faults"), ("/api/v1/faults/stream", "faults"),
    ("/api/v1/apps/x/logs", "logs"), ("/api/v1/apps/x/configurations/p", "configurations"),
    ("/api/v1/apps/x/operations/o/executions", "operations"), ("/api/v1/apps/x/triggers/t/events", "triggers"),
    ("/api/v1/apps/x/cyclic-subscriptions", "subscriptions"), ("/api/v1/", "server"), ("/api/v1/health", "server"),
    ("/api/v1/apps/x/docs", "server"), ("/api/v1/updates", "other"), ("/api/v1/apps/x/locks", "other"),
    ("/metrics", "other"), ("/api/v12/apps", "other"),
])
def test_every_path_has_one_family(path, family):
    assert fleet.family_of(path) == family
    assert family in fleet.FAMILIES


def test_keys():
    assert fleet.alive_key("robot_a") == "sovd/robot_a/alive"
    assert fleet.query_key("robot_a", "faults") == "sovd/robot_a/read/faults"
    assert fleet.query_key("*", "data", write=True) == "sovd/*/write/data"
    assert fleet.queryable_keys("r") == ("sovd/r/read/**", "sovd/r/write/**")
    assert fleet.event_key("r", "triggers", "t1") == "sovd/r/events/triggers/t1"
    assert fleet.parse_key("sovd/robot_a/events/faults") == ("robot_a", "events", "faults")
    assert fleet.parse_key("sovd/robot_a/alive") == ("robot_a", "alive", "")
    assert fleet.parse_key("sovd/*/alive") is None and fleet.parse_key("other/robot_a/alive") is None
    assert fleet.query_parts("sovd/*/read/faults") == ("read", "faults")
    assert fleet.query_parts("sovd/a/read/faults/x") == ("", "")


@pytest.mark.parametrize("name, ok", [("robot_a", True), ("r-7", True), ("a_b_c", True), ("a__b", False),
                                      ("_a", False), ("a_", False), ("a/b", False), ("", False), ("*", False),
                                      ("a" * 64, True), ("a" * 65, False), (7, False)])
def test_fleet_ids(name, ok):
    assert fleet.valid_fleet_id(name) is ok


def test_a_request_goes_and_comes_back_with_only_the_headers_that_go_along():
    frame = fleet.request("PUT", "/api/v1/apps/x/data/t", "a=1", {"Authorization": "Bearer t", "Cookie": "no",
                                                                  "X-Client-Id": "me"}, b"{}", 1500)
    req = fleet.read_request(frame)
    assert (req["m"], req["p"], req["q"], req["b"], req["t"]) == ("PUT", "/api/v1/apps/x/data/t", "a=1", b"{}", 1500)
    assert req["h"] == {"Authorization": "Bearer t", "X-Client-Id": "me"}


def _raw(**fields) -> bytes:
    base = {"v": fleet.VERSION, "m": "GET", "p": "/api/v1/faults", "q": "", "h": {}, "b": b"", "t": 1000}
    return msgpack.packb({**base, **fields}, use_bin_type=True)


@pytest.mark.parametrize("fields", [
    {"v": 2}, {"m": "TRACE"}, {"p": "/metrics"}, {"p": "/api/v1/apps?x=1"}, {"p": "/api/v1/a\r\nb"},
    {"q": "a\nb"}, {"h": {"Cookie": "x"}}, {"h": {"Authorization": "a\r\nInjected: 1"}},
    {"b": "text"}, {"b": b"x" * (fleet.MAX_REQUEST + 1)}, {"t": 0}, {"t": True}, {"t": 10**9},
    {"p": "/api/v1/" + "a" * 5000}, {"p": "/api/v1/../../metrics"}, {"p": "/api/v1/apps/./x"},
])
def test_a_request_that_is_not_one_of_ours_is_refused(fields):
    with pytest.raises(fleet.WireError):
        fleet.read_request(_raw(**fields))


def test_garbage_is_refused():
    for frame in (b"", b"\xc1", msgpack.packb([1, 2]), msgpack.packb({"v": 1}) + b"x"):
        with pytest.raises(fleet.WireError):
            fleet.read_request(frame)


def test_a_reply_keeps_its_status_body_and_the_headers_that_come_back():
    frame = fleet.reply(201, b"{}", {"Location": "/api/v1/x", "Set-Cookie": "no", "Content-Type": "application/json"})
    assert fleet.read_reply(frame) == (201, {"Location": "/api/v1/x", "Content-Type": "application/json"}, b"{}")
    status, headers, body = fleet.read_reply(fleet.error_reply(403, "forbidden", "no", fleet_id="r"))
    assert status == 403 and headers == {"Content-Type": "application/json"}
    assert body == b'{"error_code":"forbidden","message":"no","parameters":{"fleet_id":"r"}}'
    with pytest.raises(fleet.WireError):
        fleet.read_reply(msgpack.packb({"v": 1, "s": 99, "h": {}, "b": b""}))
