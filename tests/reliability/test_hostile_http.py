"""Scenario 5, hostile HTTP input against a gateway started with ``--allow-publish``.

- schemathesis generates requests from the gateway's own OpenAPI document
  (``/api/v1/docs``), valid and invalid, with random and with real entity
  ids, and checks each answer against the document;
- a hypothesis fuzzer sends PUT bodies of installed message types with
  random data, so that hostile values go all the way to the ROS worker;
- hand-made cases: path traversal, NUL bytes, overlong ids and topics,
  invalid percent-encoding, CRLF injection, malformed HTTP, 10k-deep and
  huge JSON bodies, wrong content types, module names as message types.

What must hold: no 5xx but the documented ones (503/504 vendor errors);
every answer that reaches the app is a JSON body of the contract; the ROS
worker and the HTTP workers never restart because of input; nothing is
logged as an unhandled error.  Malformed HTTP that gunicorn refuses itself
may get gunicorn's own 4xx (not JSON), never a 5xx.
"""

from __future__ import annotations

import collections
import json
import socket
import time

import pytest
import requests
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from ipc.client import RosWorkerClient
from tests.reliability import load
from tests.support.rospub import RosNode

FUZZ_CASES = load.scaled(500, 5000)
BODY_CASES = load.scaled(300, 3000)
LIMIT = 65536  # --max-body-bytes of the gateway under attack
SINK = "/hostile/sink"


@pytest.fixture(scope="module")
def target():
    node = RosNode({"node": "hostile_pubs",
                    "publish": [{"topic": "/hostile/live", "type": "std_msgs/msg/Float64", "rate": 20}],
                    "subscribe": [{"topic": SINK, "type": "std_msgs/msg/String"}]})
    gw = Gateway("--allow-publish", "--max-body-bytes", str(LIMIT), "--log-level", "info")
    try:
        host = gw.get("/components").json()["items"][0]["id"]
        poll_until(lambda: gw.get(f"/components/{host}/data/hostile/live").json()["x-medkit"]["status"]
                   == "data", 30, message="live topic")
        poll_until(lambda: "hostile_pubs" in {a["id"] for a in gw.get("/apps").json()["items"]}, 30,
                   message="hostile_pubs listed")
        yield gw, host
    finally:
        gw.stop()
        node.stop()


def identity(gw) -> tuple[int, tuple[int, ...]]:
    """The ROS worker's pid (as its own socket tells) and the HTTP workers' pids."""
    client = RosWorkerClient.for_runtime_dir(gw.runtime_dir)
    try:
        pid = client.call("ping", timeout=5)["pid"]
    finally:
        client.close()
    return pid, tuple(sorted(p.pid for p in load.gateway_procs(gw.pid).http))


def unharmed(gw, before: tuple[int, tuple[int, ...]], log_from: int) -> None:
    """Same ROS worker, same HTTP workers, no unhandled error logged, still serving."""
    assert gw.proc.poll() is None
    assert identity(gw) == before, "a worker was restarted by hostile input"
    log = "\n".join(gw.output[log_from:])
    for marker in ("Traceback", "Unhandled error", "Internal error in the ROS worker", "[CRITICAL]",
                   "Beautiful is better than ugly"):  # the last: `import this` ran
        assert marker not in log, f"{marker!r} in the gateway's log:\n{log[-3000:]}"
    assert gw.get("/health").json()["x-medkit-subscription-executor"]["worker_alive"]


def release_locks(gw, entities: dict[str, str]) -> None:
    """Free the entities of locks a fuzzed client took (under X-Client-Ids nobody knows): take each
    lock over (``break_lock``) and release it, so the next tests' writes are not refused 409."""
    for collection, entity_id in entities.items():
        base = f"{gw.api}/{collection}/{entity_id}/locks"
        mine = {"X-Client-Id": "hostile-cleanup"}
        taken = requests.post(base, json={"lock_expiration": 5, "break_lock": True}, headers=mine, timeout=10)
        assert taken.status_code == 201, taken.text
        assert requests.delete(f"{base}/{taken.json()['id']}", headers=mine, timeout=10).status_code == 204
        assert requests.get(base, timeout=10).json()["items"] == []


# --------------------------------------------------------------------------------- schemathesis
def test_schemathesis_against_the_openapi_document(target):
    import schemathesis
    from schemathesis import GenerationMode
    from schemathesis.specs.openapi.checks import (
        content_type_conformance,
        negative_data_rejection,
        response_headers_conformance,
        response_schema_conformance,
        status_code_conformance,
    )

    gw, host = target
    before, log_from = identity(gw), len(gw.output)
    schema = schemathesis.openapi.from_url(gw.api + "/docs", timeout=10)
    real_ids = {"component_id": host, "app_id": "hostile_pubs", "function_id": "root", "area_id": "root"}
    strategy = st.one_of(
        schema.as_strategy(generation_mode=GenerationMode.POSITIVE),
        schema.as_strategy(generation_mode=GenerationMode.NEGATIVE),
        schema.as_strategy(generation_mode=GenerationMode.POSITIVE, path_parameters=real_ids),
        schema.as_strategy(generation_mode=GenerationMode.NEGATIVE, path_parameters=real_ids),
    )
    checks = [status_code_conformance, content_type_conformance, response_schema_conformance,
              response_headers_conformance, negative_data_rejection]
    session = requests.Session()
    answers: list[load.Answer] = []
    failures: list[str] = []

    @settings(max_examples=FUZZ_CASES, deadline=None, database=None, phases=[Phase.generate],
              suppress_health_check=list(HealthCheck))
    @given(case=strategy)
    def fuzz(case):
        started = time.monotonic()
        try:
            response = case.call(base_url=gw.api, session=session, timeout=20)
        except requests.RequestException as exc:
            answers.append(load.Answer("fuzz", case.path, started, time.monotonic() - started,
                                  type(exc).__name__, type(exc).__name__, None))
            failures.append(f"{case.method} {case.path}: {exc!r}")
            return
        headers = {k.lower(): (v[0] if isinstance(v, list) else v) for k, v in response.headers.items()}
        body = response.content or b""
        wrong = load.problem(response.status_code, headers, body) if case.method != "HEAD" else None
        answers.append(load.Answer("fuzz", case.path, started, time.monotonic() - started,
                              response.status_code, load.error_key(response.status_code, body), wrong))
        if wrong:
            failures.append(f"{case.method} {case.formatted_path}: {wrong}")
        try:
            case.validate_response(response, checks=checks)
        except BaseException as exc:  # schemathesis raises a FailureGroup (an exception group)
            if isinstance(exc, KeyboardInterrupt):
                raise
            failures.append(f"{case.method} {case.formatted_path}: {str(exc)[:400]}")

    fuzz()
    session.close()
    release_locks(gw, {"components": host, "apps": "hostile_pubs"})  # the fuzz may have taken some
    load.record("hostile HTTP: schemathesis", answers, restarts=0 if identity(gw) == before else None,
           note=f"{len(answers)} generated cases from /api/v1/docs")
    assert not failures, f"{len(failures)} failures, e.g.:\n" + "\n".join(failures[:10])
    unharmed(gw, before, log_from)


# --------------------------------------------------------------------------------- PUT bodies
SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=False, allow_infinity=False), st.text(max_size=40),
    st.text(alphabet=st.characters(codec="utf-8"), max_size=5).map(lambda s: s + "\x00"),
)
JSON = st.recursive(SCALARS, lambda inner: st.one_of(
    st.lists(inner, max_size=6), st.dictionaries(st.text(max_size=12), inner, max_size=6)), max_leaves=30)
TYPES = {
    "std_msgs/msg/String": ["data"],
    "std_msgs/msg/Int32": ["data"],
    "std_msgs/msg/UInt8MultiArray": ["data", "layout"],
    "std_msgs/msg/Header": ["stamp", "frame_id"],
    "geometry_msgs/msg/Twist": ["linear", "angular"],
    "geometry_msgs/msg/PoseWithCovariance": ["pose", "covariance"],
    "sensor_msgs/msg/Image": ["header", "height", "width", "encoding", "is_bigendian", "step", "data"],
    "diagnostic_msgs/msg/DiagnosticArray": ["header", "status"],
    "nav_msgs/msg/Odometry": ["header", "child_frame_id", "pose", "twist"],
}


@st.composite
def publish_bodies(draw):
    type_name = draw(st.sampled_from(sorted(TYPES)))
    fields = TYPES[type_name]
    keys = draw(st.lists(st.one_of(st.sampled_from(fields), st.text(max_size=8)), max_size=5, unique=True))
    data = {k: draw(JSON) for k in keys}
    return {"type": type_name, "data": data}


def test_fuzzed_publish_bodies_reach_the_ros_worker_and_never_hurt_it(target):
    gw, host = target
    before, log_from = identity(gw), len(gw.output)
    path = f"{gw.api}/components/{host}/data/hostile/fuzzed"
    session = requests.Session()
    answers: list[load.Answer] = []
    failures: list[str] = []

    @settings(max_examples=BODY_CASES, deadline=None, database=None, phases=[Phase.generate],
              suppress_health_check=list(HealthCheck))
    @given(body=publish_bodies())
    def fuzz(body):
        started = time.monotonic()
        raw = json.dumps(body).encode()
        r = session.put(path, data=raw, headers={"Content-Type": "application/json"}, timeout=20)
        headers = {k.lower(): v for k, v in r.headers.items()}
        wrong = load.problem(r.status_code, headers, r.content)
        answers.append(load.Answer("body", path, started, time.monotonic() - started, r.status_code,
                              load.error_key(r.status_code, r.content), wrong))
        if wrong or r.status_code not in (200, 400, 413):
            failures.append(f"{raw[:200]!r}: {r.status_code} {wrong or r.text[:200]}")

    fuzz()
    session.close()
    load.record("hostile HTTP: PUT bodies", answers, note="random data for installed message types")
    assert not failures, f"{len(failures)} failures, e.g.:\n" + "\n".join(failures[:10])
    assert any(a.status == 200 for a in answers) and any(a.status == 400 for a in answers)
    unharmed(gw, before, log_from)


# --------------------------------------------------------------------------------- hand-made
def http_request(method: str, path: str, body: bytes = b"", headers: dict[str, str] | None = None,
                 version: str = "HTTP/1.1") -> bytes:
    head = {"Host": "127.0.0.1", "Connection": "close", **(headers or {})}
    if body and "Content-Length" not in head and head.get("Transfer-Encoding") != "chunked":
        head["Content-Length"] = str(len(body))
    lines = [f"{method} {path} {version}"] + [f"{k}: {v}" for k, v in head.items()]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1") + body


def parse_answer(raw: bytes) -> tuple[dict[str, str], bytes]:
    head, _, body = raw.partition(b"\r\n\r\n")
    headers = {}
    for line in head.split(b"\r\n")[1:]:
        name, _, value = line.decode("latin-1").partition(":")
        headers[name.strip().lower()] = value.strip()
    if headers.get("transfer-encoding") == "chunked":
        out, rest = b"", body
        while rest:
            size_line, _, rest = rest.partition(b"\r\n")
            size = int(size_line.split(b";")[0] or b"0", 16)
            if size == 0:
                break
            out, rest = out + rest[:size], rest[size + 2:]
        body = out
    return headers, body


def chunked(body: bytes, size: int = 65536) -> bytes:
    parts = [b"%x\r\n%s\r\n" % (len(body[i:i + size]), body[i:i + size]) for i in range(0, len(body), size)]
    return b"".join(parts) + b"0\r\n\r\n"


def pub(type_name: str, data) -> bytes:
    return json.dumps({"type": type_name, "data": data}).encode()


APP = "JSON"      # the answer comes from the app: contract JSON
SERVER = "SERVER"  # malformed HTTP: gunicorn may answer itself (any 4xx) or close


def hand_made_cases(host: str) -> list[tuple[str, bytes, set[int], str]]:
    """``(name, raw request, acceptable statuses, APP|SERVER)``."""
    d = f"/api/v1/components/{host}/data"
    sink = d + SINK
    get = lambda path: http_request("GET", path)  # noqa: E731
    put = lambda body, **h: http_request("PUT", sink, body, {"Content-Type": "application/json", **h})  # noqa: E731
    deep = b'{"type":"std_msgs/msg/String","data":' + b'{"a":' * 10000 + b"1" + b"}" * 10000 + b"}"
    cases = [
        # path traversal
        ("traversal through apps", get("/api/v1/apps/../../../../etc/passwd"), {400, 404}, APP),
        ("traversal in data_id", get(f"{d}/../../../../etc/passwd"), {400}, APP),
        ("encoded traversal in data_id", get(f"{d}/%2e%2e%2f%2e%2e%2fetc%2fpasswd"), {400}, APP),
        ("encoded traversal as entity id", get("/api/v1/apps/%2e%2e/data"), {400, 404}, APP),
        ("encoded traversal at the root", get("/api/v1/%2e%2e/%2e%2e/etc/passwd"), {404}, APP),
        ("double-encoded traversal", get(f"{d}/%252e%252e%252fetc%252fpasswd"), {400}, APP),
        ("backslash traversal", get(f"{d}/..\\..\\etc\\passwd"), {400}, APP),
        # NUL bytes
        ("%00 in entity id", get("/api/v1/apps/a%00b/data"), {400}, APP),
        ("%00 in topic", get(f"{d}/a%00b"), {400}, APP),
        ("%00 as topic", get(f"{d}/%00"), {400}, APP),
        ("%00 in PUT topic", http_request("PUT", f"{d}/x%00y", pub("std_msgs/msg/String", {"data": "x"}),
                                          {"Content-Type": "application/json"}), {400}, APP),
        ("raw NUL in the path", b"GET /api/v1/apps/a\x00b HTTP/1.1\r\nHost: x\r\n\r\n", set(), SERVER),
        # overlong
        ("entity id of 257", get("/api/v1/apps/" + "a" * 257), {400}, APP),
        ("entity id of 5000", get("/api/v1/apps/" + "a" * 5000 + "/data"), {400}, APP),
        ("topic of 256", get(f"{d}/" + "a" * 256), {400}, APP),
        ("topic of 3000 levels", get(f"{d}/" + "a/" * 3000 + "a"), {400}, APP),
        ("empty topic", get(f"{d}/"), {400}, APP),
        ("request line past the limit", get(f"{d}/" + "a" * 9000), set(), SERVER),
        ("header past the limit", http_request("GET", "/api/v1/health", headers={"X-Big": "a" * 9000}),
         set(), SERVER),
        ("200 headers", http_request("GET", "/api/v1/health", headers={f"X-H{i}": "v" for i in range(200)}),
         set(), SERVER),
        # encodings
        ("percent not followed by hex", get(f"{d}/%zz"), {400}, APP),
        ("percent at the end", get(f"{d}/abc%"), {400}, APP),
        ("percent with one digit", get(f"{d}/abc%4"), {400}, APP),
        ("latin-1 byte, not UTF-8", get(f"{d}/caf%e9"), {400}, APP),
        ("overlong UTF-8 slash", get(f"{d}/a%c0%afb"), {400}, APP),
        ("invalid UTF-8 entity id", get("/api/v1/apps/%ff%fe"), {400}, APP),
        ("non-ASCII topic", get(f"{d}/temp%C3%A9rature"), {400}, APP),
        ("raw UTF-8 bytes in the path", f"GET {d}/temp\u00e9 HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
         .encode(), {400}, SERVER),
        ("newline in topic", get(f"{d}/a%0ab"), {400}, APP),
        ("CRLF header injection", get(f"{d}/a%0d%0aSet-Cookie:%20pwned=1"), {400}, APP),
        ("format string id", get("/api/v1/apps/%25s%25s%25n"), {400}, APP),
        ("quote in id", get("/api/v1/apps/x'%20OR%201=1--"), {400}, APP),
        ("%00 bytes parameter", get(f"{d}/hostile/live?bytes=%00"), {400}, APP),
        ("huge bytes parameter", get(f"{d}/hostile/live?bytes=" + "x" * 5000), {400}, APP),
        ("repeated bytes parameter", get(f"{d}/hostile/live?bytes=base64&bytes=array"), {200}, APP),
        ("long query string", get("/api/v1/health?" + "a=b&" * 1500), {200}, APP),
        ("unknown collection", get("/api/v1/robots/x/data"), {404}, APP),
        ("doubled slashes", get("//api//v1//apps"), {404}, APP),
        # methods
        ("DELETE a data item", http_request("DELETE", f"{d}/hostile/live"), {405}, APP),
        ("POST a data item", http_request("POST", sink, pub("std_msgs/msg/String", {"data": "x"})), {405}, APP),
        ("PATCH /health", http_request("PATCH", "/api/v1/health"), {405}, APP),
        ("TRACE", http_request("TRACE", "/api/v1/health"), {405}, APP),
        ("made-up method", http_request("BREW", "/api/v1/health"), {405, 400}, SERVER),
        # malformed HTTP
        ("control byte in the method", b"G\x01T /api/v1/health HTTP/1.1\r\nHost: x\r\n\r\n", set(), SERVER),
        ("HTTP/0.9", b"GET /api/v1/health\r\n\r\n", set(), SERVER),
        ("HTTP/2 preface on HTTP/1", b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n", set(), SERVER),
        ("unknown HTTP version", http_request("GET", "/api/v1/health", version="HTTP/7.1"), {505}, SERVER),
        ("two Content-Lengths", http_request("PUT", sink, b'{"a":1}', {"Content-Length": "7",
                                                                        "content-length": "70"}), set(), SERVER),
        ("negative Content-Length", http_request("PUT", sink, b"{}", {"Content-Length": "-2"}), set(), SERVER),
        ("Content-Length and chunked", http_request(
            "PUT", sink, chunked(pub("std_msgs/msg/String", {"data": "x"})),
            {"Content-Length": "5", "Transfer-Encoding": "chunked", "Content-Type": "application/json"}),
         set(), SERVER),
        ("body shorter than Content-Length", http_request("PUT", sink, b'{"type"', {"Content-Length": "500"}),
         {400}, SERVER),
        ("obsolete header folding", b"GET /api/v1/health HTTP/1.1\r\nHost: x\r\nX-A: a\r\n b\r\n\r\n",
         {200}, SERVER),
        # bodies
        ("JSON nested 10000 deep", put(deep), {400}, APP),
        ("arrays nested 30000 deep", put(b"[" * 30000 + b"]" * 30000), {400}, APP),
        ("data nested 400 deep", put(b'{"type":"std_msgs/msg/String","data":' + b'{"data":' * 400 + b'"x"'
                                     + b"}" * 401), {400}, APP),
        ("body past the limit", put(b" " * (LIMIT + 1)), {413}, APP),
        ("chunked body past the limit", put(chunked(b" " * (4 * LIMIT)), **{"Transfer-Encoding": "chunked"}),
         {413}, APP),
        ("body of 16 MiB", put(b"[" + b"0," * (8 * 2**20) + b"0]"), {413}, APP),
        ("string just under the limit", put(pub("std_msgs/msg/String", {"data": "x" * (LIMIT - 64)})), {200}, APP),
        ("integer past 64 bits", put(b'{"type":"std_msgs/msg/Int64","data":{"data":' + b"9" * 400 + b"}}"),
         {400}, APP),
        ("NaN literal", put(b'{"type":"std_msgs/msg/Float64","data":{"data":NaN}}'), {400}, APP),
        ("1e999", put(b'{"type":"std_msgs/msg/Float64","data":{"data":1e999}}'), {200, 400}, APP),
        ("invalid UTF-8 body", put(b'{"type":"std_msgs/msg/String","data":{"data":"\xff\xfe"}}'), {400}, APP),
        ("UTF-16 body", put("\ufeff".encode("utf-16-le") + pub("std_msgs/msg/String", {"data": "x"})
                            .decode().encode("utf-16-le")), {400}, APP),
        ("empty body", http_request("PUT", sink, b"", {"Content-Type": "application/json",
                                                       "Content-Length": "0"}), {400}, APP),
        ("body null", put(b"null"), {400}, APP),
        ("body a list", put(b"[1,2]"), {400}, APP),
        ("body a string", put(b'"std_msgs/msg/String"'), {400}, APP),
        ("duplicate keys", put(b'{"type":"std_msgs/msg/String","type":"x/msg/Y","data":{"data":"x"}}'),
         {200, 400}, APP),
        ("NUL in a string field", put(pub("std_msgs/msg/String", {"data": "a\x00b"})), {200, 400}, APP),
        ("unknown field", put(pub("std_msgs/msg/String", {"data": "x", "nope": 1})), {400}, APP),
        ("Int32 out of range", put(pub("std_msgs/msg/Int32", {"data": 2**31})), {400}, APP),
        ("uint8 out of range", put(pub("std_msgs/msg/UInt8MultiArray", {"data": [256]})), {400}, APP),
        ("fixed array too long", put(pub("geometry_msgs/msg/PoseWithCovariance",
                                         {"covariance": [0.0] * 5000})), {400}, APP),
        ("key of 50000 characters", put(pub("std_msgs/msg/String", {"k" * 50000: 1})), {400}, APP),
        # wrong content types: refused (415) even when the body is JSON (app/core/bodies.py)
        ("text/plain", put(pub("std_msgs/msg/String", {"data": "x"}), **{"Content-Type": "text/plain"}),
         {415}, APP),
        ("form-urlencoded", put(b"type=std_msgs%2Fmsg%2FString&data=x",
                                **{"Content-Type": "application/x-www-form-urlencoded"}), {415}, APP),
        ("multipart", put(b"--b\r\nContent-Disposition: form-data; name=\"type\"\r\n\r\nx\r\n--b--\r\n",
                          **{"Content-Type": "multipart/form-data; boundary=b"}), {415}, APP),
        ("xml", put(b"<type>std_msgs/msg/String</type>", **{"Content-Type": "application/xml"}),
         {415}, APP),
        ("no content type", http_request("PUT", sink, pub("std_msgs/msg/String", {"data": "x"})),
         {415}, APP),
        ("JSON with charset=utf-16", put(pub("std_msgs/msg/String", {"data": "x"}),
                                         **{"Content-Type": "application/json; charset=utf-16"}),
         {200, 400, 415}, APP),
    ]
    # Module names as message types: refused without importing anything.
    for bad in ("../../msg/X", "os/msg/system", "antigravity/msg/X", "this/msg/Zen", "std_msgs/msg/__init__",
                "std_msgs/msg/String\u0000", "builtins/msg/object", "rclpy/msg/Node", "sys/msg/modules",
                "subprocess/msg/Popen", "std_msgs/msg/_string", "std_msgs/srv/Empty", "a" * 300 + "/msg/X"):
        cases.append((f"message type {bad[:30]!r}", put(pub(bad, {})), {400}, APP))
    return cases


def test_hand_made_hostile_requests(target):
    gw, host = target
    before, log_from = identity(gw), len(gw.output)
    rss_before = load.memory(gw.pid)
    failures, statuses = [], collections.Counter()
    worst = 0.0
    for name, raw, expected, origin in hand_made_cases(host):
        started = time.monotonic()
        status, answer = load.raw_exchange(gw.port, raw, timeout=20)
        worst = max(worst, time.monotonic() - started)
        statuses[str(status)] += 1
        headers, body = parse_answer(answer)
        if origin == APP:
            if status not in expected:
                failures.append(f"{name}: {status} (expected {sorted(expected)}): {body[:200]!r}")
                continue
            wrong = load.problem(status, headers, body)
            if wrong:
                failures.append(f"{name}: {wrong}")
        else:  # gunicorn's own answer, or none: never a 5xx (but 505 when asked for), never a hang
            if status is not None and status >= 500 and status not in expected:
                failures.append(f"{name}: {status} {answer[:200]!r}")
            elif status is not None and status not in expected and not 400 <= status < 500:
                failures.append(f"{name}: {status} (expected a 4xx): {answer[:200]!r}")
        if "set-cookie" in headers:
            failures.append(f"{name}: answered with Set-Cookie {headers['set-cookie']!r}")
        if b"root:" in body:
            failures.append(f"{name}: the answer looks like /etc/passwd")
    load.record("hostile HTTP: hand-made", requests=sum(statuses.values()), statuses=dict(statuses),
           worst_ms=worst * 1000, restarts=0 if identity(gw) == before else None,
           rss_before=rss_before, rss_after=load.memory(gw.pid),
           note="traversal, NUL, overlong, encodings, malformed HTTP, bodies, types")
    assert not failures, f"{len(failures)} hostile requests were mishandled:\n" + "\n".join(failures)
    unharmed(gw, before, log_from)


def body_routes(gw, host: str) -> dict[str, tuple[str, str, bytes]]:
    """``name: (method, path, a valid JSON body)`` of every route that takes a JSON body."""
    base = f"/api/v1/components/{host}/cyclic-subscriptions"
    resource = f"/api/v1/components/{host}/data/hostile/live"
    sub = {"resource": resource, "interval": "slow", "duration": 60}
    made = requests.post(gw.api + base.removeprefix("/api/v1"), json=sub, timeout=15)
    assert made.status_code == 201, made.text
    return {
        "PUT data": ("PUT", f"/api/v1/components/{host}/data{SINK}", pub("std_msgs/msg/String", {"data": "x"})),
        "POST cyclic-subscriptions": ("POST", base, json.dumps(sub).encode()),
        "PUT cyclic-subscriptions": ("PUT", f"{base}/{made.json()['id']}", b'{"interval": "normal"}'),
    }


def subscriptions_of(gw, host: str) -> list[str]:
    r = gw.get(f"/components/{host}/cyclic-subscriptions")
    assert r.status_code == 200, r.text
    return sorted(s["id"] for s in r.json()["items"])


@pytest.mark.parametrize("route", ["PUT data", "POST cyclic-subscriptions", "PUT cyclic-subscriptions"])
def test_every_json_body_route_refuses_bad_bodies_alike(target, route):
    """One body reader (``app/core/bodies.py``) for every route that takes a JSON body.

    BUGS (issue 18, defects 3 and 9), on the subscription routes: a malformed
    chunked body got 500 with a traceback in the log (PUT data: 400); a
    chunked body past the limit was cut at the limit and got "not valid JSON"
    instead of 413; and a body declared ``text/plain`` (what a page of another
    web site may send without a preflight) was read as JSON and created a
    subscription.
    """
    gw, host = target
    method, path, good = body_routes(gw, host)[route]
    subs_before = subscriptions_of(gw, host)
    log_from = len(gw.output)

    def send(body: bytes, headers: dict[str, str]) -> tuple[int | None, dict[str, str], bytes]:
        status, answer = load.raw_exchange(gw.port, http_request(method, path, body, headers), timeout=20)
        return (status, *parse_answer(answer))

    json_type = {"Content-Type": "application/json"}
    is_chunked = {"Transfer-Encoding": "chunked", **json_type}
    cases = {
        # malformed chunked bodies: the client's error, 400
        "chunk size not hex": (b"zz\r\nabc\r\n0\r\n\r\n", is_chunked, 400),
        "chunk shorter than its size": (b"5\r\nabc\r\n0\r\n\r\n", is_chunked, 400),
        "chunk without its CRLF": (b"3\r\nabcXX0\r\n\r\n", is_chunked, 400),
        "body ends inside a chunk": (b"10\r\nabc", is_chunked, 400),
        # past the limit: 413 whether sized or chunked, never a body cut at the limit
        "Content-Length past the limit": (b" " * (LIMIT + 1), json_type, 413),
        "chunked past the limit": (chunked(b" " * (4 * LIMIT)), is_chunked, 413),
        # not declared JSON: 415, even when the body is valid JSON
        "text/plain": (good, {"Content-Type": "text/plain"}, 415),
        "text/plain chunked": (chunked(good), {"Content-Type": "text/plain", "Transfer-Encoding": "chunked"}, 415),
        "form-urlencoded": (good, {"Content-Type": "application/x-www-form-urlencoded"}, 415),
        "multipart": (good, {"Content-Type": "multipart/form-data; boundary=b"}, 415),
        "no Content-Type": (good, {}, 415),
        "a JSON-like type": (good, {"Content-Type": "application/jsonp"}, 415),
    }
    wrong = []
    for name, (body, headers, expected) in cases.items():
        status, headers_in, payload = send(body, headers)
        if status != expected or load.problem(status, headers_in, payload):
            wrong.append(f"{name}: {status} (expected {expected}) {payload[:160]!r}")
        elif expected == 415 and json.loads(payload)["error_code"] != "invalid-request":
            wrong.append(f"{name}: 415 with {payload[:160]!r}")
    assert not wrong, f"{route}: " + "; ".join(wrong)
    assert subscriptions_of(gw, host) == subs_before, "a refused body created a subscription"
    # The same body, declared JSON (any case, with a charset), is accepted.
    status, _, payload = send(good, {"Content-Type": "Application/JSON; charset=utf-8"})
    assert status in (200, 201), payload[:300]
    log = "\n".join(gw.output[log_from:])
    assert "Unhandled error" not in log and "Traceback" not in log, log[-3000:]


# --------------------------------------------------------------------------------- slow clients
def slow_clients(port: int, count: int) -> list[socket.socket]:
    """Connections that send half a request line's headers and then nothing (slowloris)."""
    socks = []
    for _ in range(count):
        s = socket.create_connection(("127.0.0.1", port), timeout=5)
        s.sendall(b"GET /api/v1/health HTTP/1.1\r\nHost: x\r\n")  # the blank line never comes
        socks.append(s)
    return socks


def health_answers(port: int, attempts: int = 3, timeout: float = 3.0) -> list[int | str]:
    out = []
    for _ in range(attempts):
        client = load.Client(port, timeout=timeout)
        try:
            out.append(client.request("GET", "/api/v1/health")[0])
        except OSError as exc:
            out.append(type(exc).__name__)
        finally:
            client.close()
    return out


def health_while_held(port: int, socks: list[socket.socket], attempts: int) -> list[int | str]:
    """``/health`` answers while ``socks`` stay open (they are closed after)."""
    try:
        time.sleep(0.5)
        return health_answers(port, attempts=attempts)
    finally:
        for s in socks:
            s.close()


def all_healthy(scenario: str, answers: list[int | str], note: str) -> None:
    load.record(scenario, requests=len(answers), statuses=dict(collections.Counter(str(a) for a in answers)), note=note)
    assert answers == [200] * len(answers), answers


def test_slow_clients_do_not_starve_the_http_workers(gateways):
    """Clients that send half a head and stall hold no thread (app/http_worker.py).

    One worker holding at most 64 connections; more stalled clients than the
    whole gateway used to have threads (2 x 8).
    """
    gw = gateways("--workers", "1", "--worker-connections", "64", "--log-level", "warning")
    answers = health_while_held(gw.port, slow_clients(gw.port, 24), attempts=1)
    all_healthy("slow clients direct", answers, "24 stalled connections vs 1 worker x 64 connections, no proxy")


def test_idle_connections_do_not_starve_the_http_workers(gateways):
    """Connections that send nothing (port scans, browser preconnects) hold no thread."""
    gw = gateways("--log-level", "warning")  # the default 2 workers x 1000 connections
    idle = [socket.create_connection(("127.0.0.1", gw.port), timeout=5) for _ in range(200)]
    answers = health_while_held(gw.port, idle, attempts=1)
    all_healthy("idle connections direct", answers,
                "200 connections that send nothing vs 2 workers x 1000 connections, no proxy")


def test_slow_clients_through_nginx_do_not_starve_the_gateway(gateways, tmp_path):
    from tests.system.test_nginx import Nginx, nginx_binary

    nginx_binary()
    gw = gateways("--workers", "1", "--worker-connections", "64", "--log-level", "warning")
    nginx = Nginx(gw.port, tmp_path / "nginx")
    try:
        socks = slow_clients(nginx.port, 40)
        socks += [socket.create_connection(("127.0.0.1", nginx.port), timeout=5) for _ in range(150)]
        answers = health_while_held(nginx.port, socks, attempts=5)
    finally:
        nginx.stop()
    all_healthy("slow/idle clients via nginx", answers,
                "40 stalled + 150 idle connections on nginx in front of 1 worker x 64 connections")


def test_pipelined_requests_all_get_answers(target):
    gw, host = target
    before, log_from = identity(gw), len(gw.output)
    pipelined = b"".join(http_request("GET", "/api/v1/health", headers={"Connection": "keep-alive"})
                         for _ in range(99)) + http_request("GET", "/api/v1/version-info")
    status, answer = load.raw_exchange(gw.port, pipelined, timeout=20)
    assert status == 200 and answer.count(b"HTTP/1.1 200 ") == 100, answer.count(b"HTTP/1.1 ")
    load.record("pipelined requests", requests=100, statuses={"200": 100}, note="100 requests in one write")
    unharmed(gw, before, log_from)
