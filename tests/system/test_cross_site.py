"""A page of another web site, in a real browser, can change nothing on the gateway (issue 18, defect 3).

A browser sends a page's "simple" cross-origin request (a POST declared
``text/plain``, a form) without asking the server first: no CORS preflight,
so the gateway's CORS settings are never consulted.  The gateway refuses every
JSON body not declared ``application/json`` (415, ``app/core/bodies.py``), and
a request declared ``application/json`` or using PUT always takes a preflight,
which a gateway without ``cors_origins`` refuses.

Debian's chromium (playwright, tests/support/browser.py) opens a page served by
a small HTTP server on another loopback port (another origin) that attacks a
real gateway (publishing on, no token) with a no-cors ``fetch`` and a
``text/plain`` form whose one field makes the body valid JSON.  Waits are on
the gateway's answers (playwright's ``expect_response``) and on the ROS
subscriber's echo, never sleeps.
"""

from __future__ import annotations

import json

import pytest

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from tests.support.browser import launch, require_chromium
from tests.support.onepage import OnePage
from tests.support.rospub import RosNode, unique_topic

PAGE = b"""<!doctype html>
<html><head><meta charset="utf-8"><title>another site</title></head><body>
<iframe name="answer"></iframe>
<script>
// What any web site can do to a gateway its visitor can reach.
async function simplePost(url, body) {
  await fetch(url, {method: "POST", mode: "no-cors", headers: {"Content-Type": "text/plain"}, body: body});
  return "sent";
}
function formPost(url, name, value) {
  // enctype text/plain sends "name=value": with name '{"a":1,"x":"' and value '"}' that is JSON.
  const form = document.createElement("form");
  form.method = "POST"; form.enctype = "text/plain"; form.action = url; form.target = "answer";
  const field = document.createElement("input");
  field.type = "hidden"; field.name = name; field.value = value;
  form.appendChild(field); document.body.appendChild(form); form.submit();
}
async function put(url, body, mode) {
  try {
    await fetch(url, {method: "PUT", mode: mode, headers: {"Content-Type": "text/plain"}, body: body});
    return "sent";
  } catch (e) {
    return "refused by the browser: " + e.name;
  }
}
</script></body></html>"""


@pytest.fixture(scope="module")
def site():
    """The other web site: http://127.0.0.1:<another port>/ (an origin of its own)."""
    with OnePage(PAGE, "text/html; charset=utf-8") as server:
        yield server.url


@pytest.fixture(scope="module")
def browser():
    require_chromium()
    with launch() as b:
        yield b


def test_a_page_of_another_origin_creates_no_subscription_and_publishes_nothing(browser, site, nodes):
    topic = unique_topic("cross_site_cmd")
    sink = RosNode({"node": "cross_site_sink",
                    "subscribe": [{"topic": topic, "type": "std_msgs/msg/String", "echo": True}]})
    nodes.append(sink)
    gw = Gateway("--allow-publish")  # publishing on and no token: only the browser's rules stand between
    try:
        host = gw.host()
        subs = f"{gw.api}/components/{host}/cyclic-subscriptions"
        data = f"{gw.api}/components/{host}/data{topic}"
        sub = {"resource": f"/api/v1/components/{host}/data{topic}", "interval": "fast", "duration": 3600}
        message = json.dumps({"type": "std_msgs/msg/String", "data": {"data": "from another site"}})
        assert site.split(":")[2] != str(gw.port)

        context = browser.new_context()
        try:
            page = context.new_page()
            page.set_default_timeout(30_000)
            page.goto(site)
            answered = []
            for _ in range(3):  # the review's page made 20; a few show it as well
                with page.expect_response(lambda r: r.url == subs and r.request.method == "POST") as fetch:
                    assert page.evaluate("([u, b]) => simplePost(u, b)", [subs, json.dumps(sub)]) == "sent"
                answered.append(fetch.value.status)
            body = json.dumps(sub)[:-1]
            with page.expect_response(lambda r: r.url == subs and r.request.method == "POST") as form:
                page.evaluate("([u, n, v]) => formPost(u, n, v)", [subs, body + ',"x":"', '"}'])
            answered.append(form.value.status)
            puts = [page.evaluate("([u, b, m]) => put(u, b, m)", [data, message, mode])
                    for mode in ("no-cors", "cors")]
        finally:
            context.close()

        # Each POST reached the gateway, and was refused for what it declared.
        assert answered == [415] * 4, answered
        assert gw.get(f"/components/{host}/cyclic-subscriptions").json()["items"] == []
        # A PUT is no simple request: the browser refuses it (no-cors) or asks first and is told no.
        assert all(p.startswith("refused by the browser") for p in puts), puts
        # What the sink heard: nothing but what a legitimate client sends after the page.
        legit = {"type": "std_msgs/msg/String", "data": {"data": "legitimate"}}
        poll_until(lambda: gw.put(f"/components/{host}/data{topic}", json=legit).json()["x-medkit"]
                   ["subscriber_count"] >= 1 and sink.echoed(), 30, interval=0.3, message="the sink's echo")
        assert {m["data"]["data"] for m in sink.echoed()} == {"legitimate"}
        assert gw.get(f"/components/{host}/cyclic-subscriptions").json()["items"] == []
    finally:
        gw.stop()
