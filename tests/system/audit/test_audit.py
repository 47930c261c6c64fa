"""The audit trail through the real gateway: a scripted session's records, exactly; filters and paging;
admin only; bounded retention; and no secret or token anywhere the gateway wrote (its output at debug
level with the access log on, its runtime and state directories, the SQLite files included).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest
import requests

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from tests.support.auth import ENV, JWT_SECRET, SECRETS, bearer, grant
from tests.support.rospub import RosNode

APP = "audit_listener"
CMD = "/audit_test/cmd"
LEGACY = "legacy-admin-token-for-audit-0123"
DATA = f"/api/v1/apps/{APP}/data{CMD}"
MESSAGE = {"type": "std_msgs/msg/String", "data": {"data": "hello"}}


@pytest.fixture(scope="module")
def listener():
    node = RosNode({"node": APP, "subscribe": [{"topic": CMD, "type": "std_msgs/msg/String"}]})
    yield node
    node.stop()


@pytest.fixture(scope="module")
def dirs(tmp_path_factory):
    return str(tmp_path_factory.mktemp("audit-state"))


@pytest.fixture(scope="module")
def gw(listener, dirs, gateway):
    gw = gateway("--auth-enabled", "--allow-publish", "--workers", "2", "--access-log", "--log-level", "debug",
                 "--state-dir", dirs, env={**ENV, "SOVD_API_TOKEN": LEGACY})
    poll_until(lambda: APP in {a["id"] for a in gw.get("/apps").json()["items"]}, 30, message="listener listed")
    return gw


def records(gw, admin: dict, **query) -> dict:
    r = gw.get("/x-medkit-audit", params=query, headers=admin)
    assert r.status_code == 200, r.text
    return r.json()


def test_a_scripted_session_is_recorded_exactly_and_nothing_written_holds_a_secret(gw, dirs):
    admin = bearer(grant(gw, "admin"))
    since = time.time()
    issued: list[str] = []
    script = []  # (request id, client id, method, path, family, entity, status, error code)

    def send(method, path, who, status, error, *, rid, headers=None, **kw):
        r = requests.request(method, gw.url + path, headers={"X-Request-Id": rid, **(headers or {})}, timeout=10, **kw)
        assert r.status_code == status, (rid, r.status_code, r.text)
        family = path.split("/")[5] if path.split("/")[3] == "apps" else path.split("/")[3]
        entity = ("apps", APP) if path.split("/")[3] == "apps" else (None, None)
        script.append((rid, who, method, path, family, *entity, status, error))
        return r

    grant_body = {"grant_type": "client_credentials", "client_id": "operator", "client_secret": SECRETS["operator"]}
    tokens = send("POST", "/api/v1/auth/authorize", "operator", 200, None, rid="s01", json=grant_body).json()
    issued += [tokens["access_token"], tokens["refresh_token"]]
    send("POST", "/api/v1/auth/authorize", None, 401, "invalid_client", rid="s02",
         json={**grant_body, "client_secret": "a-wrong-guess"})
    op = bearer(tokens)
    viewer = grant(gw, "viewer")   # (a grant of its own: recorded too, under no request id of ours)
    issued += [viewer["access_token"], viewer["refresh_token"]]
    send("PUT", DATA, "operator", 200, None, rid="s03", headers=op, json=MESSAGE)
    send("PUT", DATA, "viewer", 403, "insufficient_scope", rid="s04", headers=bearer(viewer), json=MESSAGE)
    send("PUT", DATA, None, 401, "invalid_token", rid="s05", json=MESSAGE)
    send("PUT", DATA, None, 401, "invalid_token", rid="s06", headers={"Authorization": "Bearer forged.token.here"},
         json=MESSAGE)
    lock = send("POST", f"/api/v1/apps/{APP}/locks", "operator", 201, None, rid="s07", headers=op,
                json={"lock_expiration": 60}).json()
    configurator = grant(gw, "configurator")
    issued += [configurator["access_token"], configurator["refresh_token"]]
    send("PUT", DATA, "configurator", 409, "lock-broken", rid="s08", headers=bearer(configurator), json=MESSAGE)
    send("DELETE", f"/api/v1/apps/{APP}/locks/{lock['id']}", "operator", 204, None, rid="s09", headers=op)
    send("DELETE", "/api/v1/faults", "(api-token)", 403, "forbidden", rid="s10",
         headers={"Authorization": f"Bearer {LEGACY}"})  # admin, but the robot does not permit it (the switch)
    refreshed = send("POST", "/api/v1/auth/token", "operator", 200, None, rid="s11",
                     json={"grant_type": "refresh_token", "refresh_token": tokens["refresh_token"]}).json()
    issued.append(refreshed["access_token"])
    send("POST", "/api/v1/auth/revoke", None, 200, None, rid="s12", json={"token": tokens["refresh_token"]})
    # not recorded: reads, and a path that is no route
    assert requests.get(gw.url + DATA, headers=op, timeout=10).status_code == 200
    assert requests.post(gw.url + "/api/v1/no/such/route", headers=admin, timeout=10).status_code == 404

    def ours():
        items = records(gw, admin, since=since, limit=1000)["items"]
        return [i for i in items if (i["request_id"] or "").startswith("s")]

    poll_until(lambda: len(ours()) == len(script), 10, message="every record written")
    got = sorted(ours(), key=lambda i: i["request_id"])
    assert [(i["request_id"], i["client_id"], i["method"], i["resource"], i["family"], i["collection"],
             i["entity_id"], i["status"], i["error_code"]) for i in got] == script
    assert {i["address"] for i in got} == {"127.0.0.1"}
    assert [i["role"] for i in got if i["request_id"] in ("s03", "s04", "s08", "s10")] == \
        ["operator", "viewer", "configurator", "admin"]
    everything = records(gw, admin, since=since, limit=1000)["items"]
    grants = [i for i in everything if i["resource"] == "/api/v1/auth/authorize" and i["status"] == 200]
    assert {i["client_id"] for i in grants} == {"operator", "viewer", "configurator"}

    # newest first; pages of 4 follow each other to the same list
    stamps = [i["ts_ns"] for i in everything]
    assert stamps == sorted(stamps, reverse=True)
    paged, before = [], None
    while True:
        page = records(gw, admin, since=since, limit=4, **({"before": before} if before else {}))
        paged += page["items"]
        before = page.get("next_before")
        if before is None:
            break
    assert [i["id"] for i in paged] == [i["id"] for i in everything]
    # filters
    assert {i["request_id"] for i in records(gw, admin, since=since, client_id="operator", family="data")["items"]} \
        == {"s03"}
    assert {i["status"] for i in records(gw, admin, since=since, status="4xx")["items"]} == {401, 403, 409}
    assert [i["request_id"] for i in records(gw, admin, since=since, family="locks")["items"]] == ["s09", "s07"]
    assert records(gw, admin, since=since, request_id="s08")["items"][0]["error_code"] == "lock-broken"
    # admin only
    assert gw.get("/x-medkit-audit").status_code == 401
    assert gw.get("/x-medkit-audit", headers=bearer(grant(gw, "configurator"))).status_code == 403
    r = gw.get("/x-medkit-audit", params={"limit": 0}, headers=admin)
    assert r.status_code == 400 and r.json()["error_code"] == "invalid-parameter"
    no_secret_written(gw, dirs, issued)


def no_secret_written(gw, dirs: str, issued: list[str]) -> None:
    """Nothing the gateway wrote holds a secret or a token: its output, its runtime and state dirs."""
    gw.stop()   # everything flushed, every file closed
    needles = [*SECRETS.values(), JWT_SECRET, LEGACY, *issued, "a-wrong-guess"]
    # every token is long: its signature alone would betray it
    needles += [token.rsplit(".", 1)[1] for token in issued]
    haystacks = {"output": "\n".join(gw.output).encode()}
    for root in (gw.runtime_dir, dirs):
        for path in Path(root).rglob("*"):
            if path.is_file():
                haystacks[str(path)] = path.read_bytes()
    assert any(name.endswith("access.db") for name in haystacks)
    assert b"s03" in b"".join(haystacks.values())  # the grep reads what was written
    for name, data in haystacks.items():
        for needle in needles:
            assert needle.encode() not in data, f"{needle[:12]}… found in {name}"


def test_retention_keeps_the_newest_records(listener, tmp_path):
    gateway = Gateway("--allow-publish", "--audit-max-records", "100", "--workers", "1", "--state-dir", str(tmp_path),
                      env={"SOVD_API_TOKEN": LEGACY})
    try:
        poll_until(lambda: APP in {a["id"] for a in gateway.get("/apps").json()["items"]}, 30, message="listed")
        admin = {"Authorization": f"Bearer {LEGACY}"}
        for n in range(130):
            r = gateway.request("PUT", f"/apps/{APP}/data{CMD}", json=MESSAGE, headers={**admin, "X-Request-Id": f"r{n:03d}"})
            assert r.status_code == 200

        def kept():
            return [i["request_id"] for i in gateway.get("/x-medkit-audit", params={"limit": 1000}, headers=admin)
                    .json()["items"]]

        poll_until(lambda: kept() and kept()[0] == "r129", 10, message="the last record written")
        assert kept() == [f"r{n:03d}" for n in range(129, 29, -1)]
    finally:
        gateway.stop()
    assert oct(os.stat(tmp_path / "access.db").st_mode & 0o777) == "0o600"
