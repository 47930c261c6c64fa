"""A real nginx (Debian's package) with systemd/nginx-sovd-gateway.conf in front of a real gateway.

The site file is used as it is, except for its two addresses: the upstream points at the
test gateway's port and nginx listens on a free loopback port.  Under CI (CI=true) a
missing nginx fails the test: .ci/run installs it.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import psutil
import pytest
import requests

from common.harness.gateway import Gateway
from common.harness.procs import REPO, Proc, free_port, poll_until
from tests.support.rospub import publisher
from tests.support.sse import EventStream

SITE = REPO / "systemd" / "nginx-sovd-gateway.conf"
IN_CI = os.environ.get("CI", "").lower() == "true"
TOPIC = "/nginx_test/temperature"
IMAGE = "/nginx_test/image"
IMAGE_BYTES = 30000


def nginx_binary() -> str:
    found = shutil.which("nginx") or next(
        (p for p in ("/usr/sbin/nginx", "/usr/local/sbin/nginx") if os.access(p, os.X_OK)), None)
    if found is None:
        if IN_CI:
            pytest.fail("nginx is not installed; .ci/run installs Debian's nginx-light (or nginx)")
        pytest.skip("nginx is not installed (apt-get install nginx-light)")
    return found


def site_for(upstream_port: int, listen_port: int) -> str:
    text = SITE.read_text()
    text, n = re.subn(r"server 127\.0\.0\.1:8080\b", f"server 127.0.0.1:{upstream_port}", text)
    assert n == 1, "the upstream address in the site file changed shape"
    text, n = re.subn(r"^(\s*)listen 80;", rf"\1listen 127.0.0.1:{listen_port};", text, flags=re.M)
    assert n == 1, "the listen line in the site file changed shape"
    text = re.sub(r"^\s*listen \[::\]:80;\n", "", text, flags=re.M)
    return text


class Nginx(Proc):
    """nginx with the site file (or another ``site(upstream_port, listen_port)``), up when ``health`` answers."""

    def __init__(self, upstream_port: int, prefix: Path, site=site_for, health: str = "/api/v1/health"):
        self.health = health
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.prefix = prefix
        for d in ("logs", "client_body", "proxy", "fastcgi", "uwsgi", "scgi"):
            (prefix / d).mkdir(parents=True, exist_ok=True)
        (prefix / "site.conf").write_text(site(upstream_port, self.port))
        user = "user root;\n" if os.geteuid() == 0 else ""  # workers must write the temp dirs
        (prefix / "nginx.conf").write_text(f"""{user}worker_processes 1;
events {{ worker_connections 256; }}
http {{
    default_type application/octet-stream;
    access_log {prefix}/logs/access.log;
    client_body_temp_path {prefix}/client_body;
    proxy_temp_path {prefix}/proxy;
    fastcgi_temp_path {prefix}/fastcgi;
    uwsgi_temp_path {prefix}/uwsgi;
    scgi_temp_path {prefix}/scgi;
    include {prefix}/site.conf;
}}
""")
        self.binary = nginx_binary()
        globals_ = f"daemon off; pid {prefix}/nginx.pid; error_log {prefix}/logs/error.log info;"
        self.argv = [self.binary, "-p", str(prefix), "-c", str(prefix / "nginx.conf"),
                     "-e", str(prefix / "logs" / "error.log"), "-g", globals_]
        check = subprocess.run([*self.argv, "-t"], capture_output=True, text=True, timeout=30)
        assert check.returncode == 0, "nginx -t refused the config:\n" + check.stderr
        super().__init__(self.argv, name="nginx")
        poll_until(self._up, 20, message="nginx listening")

    def _up(self) -> bool:
        if self.proc.poll() is not None:
            raise AssertionError("nginx exited:\n" + self.error_log())
        return requests.get(self.url + self.health, timeout=2).status_code == 200

    def error_log(self) -> str:
        path = self.prefix / "logs" / "error.log"
        return path.read_text() if path.exists() else ""


@pytest.fixture(scope="module")
def pubs():
    temp = publisher("nginx_temp_sensor", TOPIC, "sensor_msgs/msg/Temperature",
                     {"temperature": 36.6}, rate=20)
    image = publisher("nginx_camera", IMAGE, "sensor_msgs/msg/Image",
                      {"height": 100, "width": IMAGE_BYTES // 100, "encoding": "mono8",
                       "step": IMAGE_BYTES // 100, "data": [7] * IMAGE_BYTES}, rate=5)
    yield temp, image
    temp.stop()
    image.stop()


@pytest.fixture(scope="module")
def stack(pubs, tmp_path_factory):
    nginx_binary()
    gw = Gateway()
    try:
        nginx = Nginx(gw.port, tmp_path_factory.mktemp("nginx"))
    except BaseException:
        gw.stop()
        raise
    yield gw, nginx
    nginx.stop()
    assert gw.stop() == 0


def read_through(nginx: Nginx, comp: str, topic: str, **kw) -> requests.Response:
    return requests.get(f"{nginx.url}/api/v1/components/{comp}/data{topic}", timeout=20, **kw)


def test_live_value_through_nginx(stack):
    gw, nginx = stack
    comps = requests.get(nginx.url + "/api/v1/components", timeout=10).json()["items"]
    comp = comps[0]["id"]

    def data():
        body = read_through(nginx, comp, TOPIC).json()
        return body if body["x-medkit"]["status"] == "data" else None
    body = poll_until(data, 30, interval=0.2, message="live data through nginx")
    assert body["data"]["temperature"] == 36.6
    assert body["id"] == TOPIC


def test_large_sample_body_through_nginx(stack):
    gw, nginx = stack
    comp = requests.get(nginx.url + "/api/v1/components", timeout=10).json()["items"][0]["id"]

    def data():
        r = read_through(nginx, comp, IMAGE)
        return r if r.json()["x-medkit"]["status"] == "data" else None
    r = poll_until(data, 30, interval=0.2, message="image through nginx")
    body = r.json()
    assert body["data"]["data"] == [7] * IMAGE_BYTES
    assert body["data"]["encoding"] == "mono8"
    # Compressed on the way out when the client accepts it, intact after decoding.
    assert r.headers.get("Content-Encoding") == "gzip"


def test_errors_pass_through_as_json(stack):
    gw, nginx = stack
    r = requests.get(nginx.url + "/api/v1/no/such/route", timeout=10)
    assert r.status_code == 404
    assert r.headers["Content-Type"].startswith("application/json")
    assert r.json()["error_code"] == "resource-not-found"


def test_body_limit_is_enforced_by_nginx(stack):
    gw, nginx = stack
    comp = requests.get(nginx.url + "/api/v1/components", timeout=10).json()["items"][0]["id"]
    big = b'{"type": "std_msgs/msg/String", "data": {"data": "' + b"x" * (1024 * 1024 + 10) + b'"}}'
    r = requests.put(f"{nginx.url}/api/v1/components/{comp}/data/nginx_test/cmd", data=big,
                     headers={"Content-Type": "application/json"}, timeout=20)
    assert r.status_code == 413


def test_upstream_connections_are_reused(stack):
    """HTTP/1.1 with keepalive to gunicorn: many requests, few upstream connections."""
    gw, nginx = stack
    session = requests.Session()
    for _ in range(30):
        assert session.get(nginx.url + "/api/v1/health", timeout=10).status_code == 200
    master = next(c for c in psutil.Process(gw.pid).children() if "gunicorn" in " ".join(c.cmdline()))
    workers = master.children()
    conns = [c for w in workers for c in w.net_connections(kind="tcp")
             if c.status == psutil.CONN_ESTABLISHED and c.laddr.port == gw.port]
    # Idle keepalive connections from nginx stay open (gunicorn's keepalive is 75 s).
    assert conns, "no kept-alive upstream connection"
    assert len(conns) <= 4
    assert "upstream prematurely closed" not in nginx.error_log()


def test_event_streams_pass_through_nginx_frame_by_frame(stack):
    gw, nginx = stack
    comp = requests.get(nginx.url + "/api/v1/components", timeout=10).json()["items"][0]["id"]
    r = requests.post(f"{nginx.url}/api/v1/components/{comp}/cyclic-subscriptions", timeout=10, json={
        "resource": f"/api/v1/components/{comp}/data{TOPIC}", "interval": "normal", "duration": 60})
    assert r.status_code == 201, r.text
    sub = r.json()
    with EventStream(nginx.port, sub["event_source"]) as stream:
        assert stream.status == 200
        assert stream.headers["content-type"].startswith("text/event-stream")
        events = [stream.next(timeout=10) for _ in range(6)]
    assert all("payload" in e or "error" in e for e in events)
    # Frame by frame, not held back until nginx's buffers fill or the stream ends: the six
    # frames arrived over about a second (200 ms apart), not all at once.
    assert stream.arrivals[5] - stream.arrivals[0] > 0.5, stream.arrivals
    assert requests.delete(f"{nginx.url}/api/v1/components/{comp}/cyclic-subscriptions/{sub['id']}",
                           timeout=10).status_code == 204


def test_metrics_are_not_exposed_through_nginx_by_default(stack):
    gw, nginx = stack
    r = requests.get(nginx.url + "/metrics", timeout=10)
    assert r.status_code == 403
    assert r.json()["error_code"] == "forbidden"
    # The gateway itself, on its loopback bind, serves them.
    direct = requests.get(gw.url + "/metrics", timeout=10)
    assert direct.status_code == 200 and "sovd_ros_worker_up 1.0" in direct.text
