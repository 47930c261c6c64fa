"""The dashboard in a real browser: Debian's chromium (playwright) against a real gateway and the demo robot.

One demo robot, one gateway (publishing on, with a token) and one browser for
the module; each test gets a fresh browser context (page).  Every page is
watched (tests/support/browser.py): a console error, an uncaught exception, a
failed request or an HTTP error answer that the test did not provoke fails the
test.  Waits are playwright's own (``expect`` with a timeout) or polls of the
API to a deadline.

``SOVD_UI_SCREENSHOT=<path>`` makes the live-value test save its screenshot
there (``make screenshot`` refreshes docs/dashboard.png that way).
"""

from __future__ import annotations

import os
import re
import shutil
import sys

import pytest
import requests

from common.harness.gateway import Gateway
from common.harness.procs import Proc, poll_until
from tests.support.browser import Watch, headless_browser

TOKEN = "ui-test-token-0123456789"
# The demo robot's apps and one topic of each (demo/robot.py).
DEMO = {
    "temp_sensor": "/powertrain/engine/temperature",
    "pressure_sensor": "/chassis/brakes/pressure",
    "odometry": "/chassis/odom",
    "controller": "/body/lights/state",
    "diagnostics_agent": "/diagnostics",
    "camera": "/perception/camera/image_raw",
    "battery_monitor": "/power/battery",
}
VIEWPORT = {"width": 1360, "height": 860}
NUMBER = re.compile(r"^-?\d")


def expect(*args, **kw):
    from playwright.sync_api import expect as playwright_expect

    return playwright_expect(*args, **kw)


def demo_is_discovered(gw: Gateway) -> bool:
    host = gw.host()
    names = {i["id"] for i in gw.get(f"/components/{host}/data").json()["items"]}
    return set(DEMO.values()) | {"/body/lights/command"} <= names


@pytest.fixture(scope="module")
def browser():
    with headless_browser(15_000) as b:
        yield b


@pytest.fixture(scope="module")
def robot(browser):
    proc = Proc([sys.executable, "-m", "demo.robot"], name="demo robot")
    try:
        proc.wait_line(lambda line: line.startswith("demo robot running"), 60)
    except BaseException:
        proc.stop()
        raise
    yield proc
    proc.stop()


@pytest.fixture(scope="module")
def gw(robot, gateway):
    gw = gateway("--allow-publish", "--api-token", TOKEN)
    poll_until(lambda: demo_is_discovered(gw), 60, interval=0.2, message="the demo robot's topics")
    return gw


@pytest.fixture
def page(browser):
    context = browser.new_context(viewport=VIEWPORT)
    tab = context.new_page()
    tab.set_default_timeout(15_000)
    watch = Watch(tab)
    yield tab, watch
    problems = watch.stop()
    try:
        tab.goto("about:blank")   # pagehide: the page deletes its subscription (closing the context may not)
    finally:
        context.close()
    assert problems == [], "\n".join(problems)


def subscriptions(gw: Gateway, app: str) -> list[dict]:
    return gw.get(f"/apps/{app}/cyclic-subscriptions").json()["items"]


def none_left(gw: Gateway, app: str) -> None:
    """Wait until no page of an earlier test holds a subscription of ``app``."""
    poll_until(lambda: subscriptions(gw, app) == [], 10, message=f"no subscription of {app} left")


def sign_in(tab) -> None:
    """Give the page the gateway's token (in its header): it makes its subscriptions with it."""
    expect(tab.locator("#token")).to_be_visible()
    tab.fill("#token", TOKEN)


def open_temperature(gw: Gateway, tab):
    """Open the demo's engine temperature (no earlier page's subscription left): its live value."""
    none_left(gw, "temp_sensor")
    tab.goto(gw.url + "/ui/#/apps/temp_sensor/data/powertrain/engine/temperature")
    sign_in(tab)
    value = leaf(tab, "temperature")
    expect(value).to_have_text(NUMBER)
    return value


def leaf(tab, path: str):
    """The value of a leaf of the item view's JSON tree."""
    return tab.locator(f"#item .json .leaf[data-path='{path}'] > .val")


def test_the_tree_lists_the_demo_and_filters_by_topic_or_node(gw, page):
    tab, _ = page
    response = tab.goto(gw.url + "/")
    assert tab.url == gw.url + "/ui/"
    sign_in(tab)
    headers = response.all_headers()
    assert "default-src 'self'" in headers["content-security-policy"]
    assert headers["x-content-type-options"] == "nosniff"
    for app, topic in DEMO.items():
        expect(tab.locator(f".tree .app[data-app='{app}']").first).to_be_attached()
        expect(tab.locator(f"a.topic[data-app='{app}'][data-topic='{topic}']").first).to_be_attached()
    # The tree follows the API's links: functions → apps as well.
    expect(tab.locator(".tree details[data-key='f:perception:camera']")).to_be_attached()
    # Hidden topics (an action's _action/ topics), /rosout and /parameter_events only when asked for,
    # as `ros2 topic list` shows them.
    feedback = "/arm/long_calibration/_action/feedback"
    expect(tab.locator(".tree .app[data-app='calibration']").first).to_be_attached()
    for topic in ("/rosout", feedback):
        expect(tab.locator(f"a.topic[data-topic='{topic}']")).to_have_count(0)
    tab.check("#show-system")
    for topic in ("/rosout", feedback):
        expect(tab.locator(f"a.topic[data-topic='{topic}']").first).to_be_attached()
    tab.uncheck("#show-system")
    tab.fill("#search", "_action/feedback")           # a filter that names a hidden topic shows it
    expect(tab.locator(f"a.topic[data-topic='{feedback}']").first).to_be_attached()

    tab.fill("#search", "image_raw")                   # a topic name
    expect(tab.locator("a.topic[data-topic='/perception/camera/image_raw']").first).to_be_visible()
    expect(tab.locator(".tree .app[data-app='pressure_sensor']")).to_have_count(0)
    tab.fill("#search", "engine/temp_sensor")          # a ROS node name
    link = tab.locator("a.topic[data-topic='/powertrain/engine/temperature']").first
    expect(link).to_be_visible()
    expect(tab.locator(".tree .app[data-app='camera']")).to_have_count(0)
    link.click()
    expect(tab).to_have_url(re.compile(r"/ui/#/apps/temp_sensor/data/powertrain/engine/temperature$"))
    expect(tab.locator("#item h2")).to_have_text("/powertrain/engine/temperature")
    expect(link).to_have_attribute("aria-current", "true")
    expect(leaf(tab, "temperature")).to_have_text(NUMBER)


def test_a_live_value_changes_on_screen_and_its_fields_plot(gw, page, tmp_path):
    tab, _ = page
    none_left(gw, "pressure_sensor")
    tab.goto(gw.url + "/ui/#/apps/pressure_sensor/data/chassis/brakes/pressure")
    # The gateway wants a token to make a subscription: the view waits for it, and asks nothing.
    badge = tab.locator("#item .item-controls .badge")
    expect(badge).to_have_text("waiting for the token")
    expect(tab.locator("#item .stream-detail")).to_contain_text("bearer token")
    assert subscriptions(gw, "pressure_sensor") == []
    sign_in(tab)
    value = leaf(tab, "fluid_pressure")
    expect(value).to_have_text(NUMBER)
    first = value.text_content()
    expect(value).not_to_have_text(first, timeout=2000)    # the bound: within 2 s
    expect(tab.locator("#item .item-controls .badge")).to_have_text("live")
    meta = tab.locator("#item .meta")
    expect(meta.locator("dd[data-key='status']")).to_have_text("data")
    expect(meta.locator("dd[data-key='publishers']")).to_have_text("1")
    expect(meta.locator("dd[data-key='age']")).to_have_text(re.compile(r"\d+(\.\d)? (ms|s)$"))
    (sub,) = subscriptions(gw, "pressure_sensor")
    assert sub["interval"] == "normal"

    tab.click("#item [data-interval='fast']")               # retimes the open stream (PUT)
    poll_until(lambda: subscriptions(gw, "pressure_sensor")[0]["interval"] == "fast", 5,
               message="the subscription retimed to fast")
    assert subscriptions(gw, "pressure_sensor")[0]["id"] == sub["id"]

    tab.click("#item button.pick[data-path='fluid_pressure']")
    tab.wait_for_function("() => Number(document.querySelector('#item canvas.plot-canvas').dataset.spanMs) >= 2000",
                          timeout=20_000)
    drawn = tab.evaluate("""() => {
        const c = document.querySelector('#item canvas.plot-canvas');
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        let line = 0;   // pixels of the first series' colour, #1f6feb
        for (let i = 0; i < d.length; i += 4)
            if (Math.abs(d[i] - 0x1f) < 40 && Math.abs(d[i + 1] - 0x6f) < 40 && d[i + 2] > 200) line++;
        return line;
    }""")
    assert drawn > 100, drawn
    expect(tab.locator("#item .legend")).to_contain_text("fluid_pressure")
    # The health panel updates itself and counts this page's stream, in words.
    expect(tab.locator("#health li[data-key='streams']")).to_have_text(re.compile(r"^[1-9]\d* live streams?, "))

    # The faults and logs of the whole robot beside it (the panels follow the item's app until asked).
    expect(tab.locator("#faults-scope .scope-name")).to_have_text("pressure_sensor")
    tab.locator("#faults-scope button").click()
    expect(tab.locator("#logs-scope .scope-name")).to_have_text("whole robot")
    expect(tab.locator("#faults .fault").first).to_be_visible(timeout=45_000)   # the demo's battery or wheel
    expect(tab.locator("#logs-body .log-line[data-node='chassis.odometry']").first).to_be_attached()
    shot = os.environ.get("SOVD_UI_SCREENSHOT") or str(tmp_path / "dashboard.png")
    tab.screenshot(path=shot)
    with open(shot, "rb") as fh:
        assert fh.read(8) == b"\x89PNG\r\n\x1a\n"

    tab.evaluate("location.hash = '#/'")                   # leaving the view ends its stream
    expect(tab.locator("#item .placeholder")).to_be_visible()
    poll_until(lambda: subscriptions(gw, "pressure_sensor") == [], 5, message="the subscription deleted")


def test_an_image_topic_is_drawn_and_leaving_the_page_ends_its_stream(gw, page):
    tab, watch = page
    none_left(gw, "camera")
    tab.goto(gw.url + "/ui/#/apps/camera/data/perception/camera/image_raw")
    sign_in(tab)
    tab.wait_for_function("() => Number(document.querySelector('#item canvas.image')?.dataset.drawn) >= 1")
    image = tab.evaluate("""() => {
        const c = document.querySelector('#item canvas.image');
        return {w: c.width, h: c.height, px: Array.from(c.getContext('2d').getImageData(0, 0, c.width, c.height).data)};
    }""")
    assert (image["w"], image["h"]) == (64, 48)
    px = image["px"]
    bars = set()
    for y in range(48):
        for x in range(64):
            r, g, b, a = px[(y * 64 + x) * 4:(y * 64 + x) * 4 + 4]
            assert (r, g, a) == (4 * x, 5 * y, 255), (x, y, r, g, b, a)   # demo/robot.py's test pattern
            assert b in (40, 255)
            if b == 255:
                bars.add(x)
    assert len(bars) == 1                                  # one bright column: one whole frame
    expect(tab.locator("#item .image-box")).to_contain_text("64 × 48 rgb8")
    expect(leaf(tab, "data")).to_have_text(re.compile(r"^base64, 9216 bytes$"))   # not a list of numbers
    (sub,) = subscriptions(gw, "camera")
    assert sub["observed_resource"].endswith("?bytes=base64")

    watch.stop()                     # the page goes away: its requests are cut on purpose
    tab.goto("about:blank")
    poll_until(lambda: subscriptions(gw, "camera") == [], 10, message="the subscription deleted on pagehide")


def test_publish_through_the_form_and_read_it_back(gw, page):
    tab, watch = page
    tab.goto(gw.url + "/ui/#/apps/controller/data/body/lights/command")
    form = tab.locator("#item form.publish")
    expect(form).to_be_visible()
    box = form.locator(".field[data-field='data.data'] input[type=checkbox]")
    expect(box).not_to_be_checked()                       # std_msgs/msg/Bool's default value
    box.check()
    watch.allow("PUT", 401)
    form.locator("button[type=submit]").click()
    token_error = form.locator(".field[data-field='token'] .field-error")
    expect(token_error).to_contain_text("Missing Authorization header")   # medkit's 401 text
    form.locator(".field[data-field='token'] input").fill(TOKEN)
    form.locator("button[type=submit]").click()
    expect(form.locator(".form-status")).to_contain_text("Published")
    expect(token_error).to_have_text("")

    tab.evaluate("location.hash = '#/apps/controller/data/body/lights/state'")
    expect(leaf(tab, "data")).to_have_text('"on"', timeout=10_000)

    # A value the gateway refuses: its error stands next to the field it names; nothing is sent to ROS.
    tab.evaluate("location.hash = '#/apps/temp_sensor/data/powertrain/engine/temperature'")
    form = tab.locator("#item form.publish")
    expect(form).to_be_visible()
    expect(form.locator(".field[data-field='token'] input")).to_have_value(TOKEN)   # kept in memory
    expect(form.locator(".field[data-field='data.variance'] input")).to_have_value("0")
    form.locator(".field[data-field='data.temperature'] input").fill("warm")
    watch.allow("PUT", 400)
    form.locator("button[type=submit]").click()
    field_error = form.locator(".field[data-field='data.temperature'] .field-error")
    expect(field_error).to_contain_text("data.temperature")
    expect(form.locator(".form-status")).to_contain_text("Not published")
    expect(leaf(tab, "temperature")).to_have_text(NUMBER)


def test_without_publishing_there_is_no_form(robot, browser, page):
    tab, watch = page
    readonly = Gateway()
    try:
        poll_until(lambda: demo_is_discovered(readonly), 60, interval=0.2, message="the demo robot's topics")
        tab.goto(readonly.url + "/ui/#/apps/controller/data/body/lights/command")
        expect(tab.locator("#gateway-version")).to_contain_text("read-only")
        # The view is complete (its stream answered: nobody publishes the command topic) ...
        expect(tab.locator("#item .meta dd[data-key='status']")).to_have_text(re.compile(r"^metadata_only"))
        expect(tab.locator("#item .json")).to_contain_text("nobody publishes")
        # ... and has no form.
        expect(tab.locator("#item form.publish")).to_have_count(0)
        assert tab.locator("#item h2").text_content() == "/body/lights/command"
    finally:
        watch.stop()
        tab.goto("about:blank")
        readonly.stop()


def test_a_ros_worker_restart_is_shown_and_the_view_recovers_by_itself(gw, page):
    tab, watch = page
    # logs (issue 22): the Logs panel's read may meet the outage before the health poll does (then it pauses).
    watch.allow("GET", 503)
    value = open_temperature(gw, tab)
    badge = tab.locator("#worker-badge")
    expect(badge).to_have_attribute("data-state", "healthy")
    pid = gw.rosworker_pid()

    gw.rosworker().kill()
    expect(badge).to_have_attribute("data-state", "unavailable")
    expect(badge).to_have_text("ROS worker unavailable")
    expect(tab.locator("#health .alert")).to_contain_text("being restarted")
    expect(tab.locator("#item .stream-error")).to_contain_text("x-medkit-ros-worker-unavailable")

    expect(badge).to_have_attribute("data-state", "healthy", timeout=60_000)
    assert gw.rosworker_pid() != pid
    expect(tab.locator("#health .note")).to_contain_text("Recovered")
    expect(tab.locator("#item .stream-error")).to_be_hidden(timeout=30_000)
    before = value.text_content()
    expect(value).not_to_have_text(before, timeout=10_000)   # live again, on the same subscription
    assert len(subscriptions(gw, "temp_sensor")) == 1


def test_non_finite_floats_are_shown_and_plotted_as_such(gw, page):
    tab, _ = page
    none_left(gw, "battery_monitor")
    tab.goto(gw.url + "/ui/#/apps/battery_monitor/data/power/battery")
    sign_in(tab)
    expect(leaf(tab, "voltage")).to_have_text(NUMBER)
    # The demo's battery does not measure its temperature: NaN, which JSON cannot carry (the
    # gateway sends "NaN", or null, in a float field).
    temperature = leaf(tab, "temperature")
    expect(temperature).to_have_text(re.compile(r"^NaN( \(null\))?$"))
    expect(temperature).to_have_class(re.compile(r"\bnonfinite\b"))
    tab.click("#item button.pick[data-path='temperature']")
    tab.click("#item button.pick[data-path='voltage']")
    expect(tab.locator("#item .legend")).to_contain_text("temperature NaN")
    expect(tab.locator("#item .legend")).to_contain_text(re.compile(r"voltage 2\d\.\d"))
    tab.evaluate("location.hash = '#/'")
    poll_until(lambda: subscriptions(gw, "battery_monitor") == [], 5, message="the subscription deleted")


def test_a_hidden_tab_gives_its_stream_back_and_takes_a_new_one_when_shown(gw, page):
    tab, _ = page
    value = open_temperature(gw, tab)
    (first,) = subscriptions(gw, "temp_sensor")
    # Headless chromium never hides a tab: the page is told it is hidden, as a browser tells it.
    tab.evaluate("""() => {
        Object.defineProperty(document, 'hidden', {configurable: true, get: () => true});
        Object.defineProperty(document, 'visibilityState', {configurable: true, get: () => 'hidden'});
        document.dispatchEvent(new Event('visibilitychange'));
    }""")
    poll_until(lambda: subscriptions(gw, "temp_sensor") == [], 15, message="the hidden tab's stream ended")
    expect(tab.locator("#item .item-controls .badge")).to_have_text("closed")
    tab.evaluate("""() => {
        delete document.hidden;
        delete document.visibilityState;
        document.dispatchEvent(new Event('visibilitychange'));
    }""")
    expect(tab.locator("#item .item-controls .badge")).to_have_text("live")
    (again,) = subscriptions(gw, "temp_sensor")
    assert again["id"] != first["id"]
    expect(value).not_to_have_text(value.text_content(), timeout=5000)


def test_a_stream_that_ends_is_replaced_by_itself(gw, page):
    tab, _ = page
    value = open_temperature(gw, tab)
    (first,) = subscriptions(gw, "temp_sensor")
    # Another client deletes it (as expiry would end it): the gateway ends the stream at once.
    r = requests.delete(f"{gw.api}/apps/temp_sensor/cyclic-subscriptions/{first['id']}", timeout=10,
                        headers={"Authorization": f"Bearer {TOKEN}"})
    assert r.status_code == 204
    again = poll_until(lambda: subscriptions(gw, "temp_sensor"), 15, message="a new subscription")
    assert [s["id"] for s in again] != [first["id"]] and len(again) == 1
    expect(tab.locator("#item .item-controls .badge")).to_have_text("live")
    expect(value).not_to_have_text(value.text_content(), timeout=5000)


def test_the_subscription_is_renewed_before_it_expires(gw, page):
    tab, _ = page
    none_left(gw, "odometry")
    tab.clock.install()               # the page's timers, under the test's control
    tab.goto(gw.url + "/ui/#/apps/odometry/data/chassis/odom")
    sign_in(tab)
    expect(leaf(tab, "pose.pose.position.x")).to_have_text(NUMBER)
    (sub,) = subscriptions(gw, "odometry")
    tab.clock.fast_forward("01:01")   # past half its duration (120 s)
    renewed = poll_until(lambda: [s for s in subscriptions(gw, "odometry") if s["expires_at"] != sub["expires_at"]],
                         10, message="the subscription renewed (PUT duration)")
    assert [s["id"] for s in renewed] == [sub["id"]] and renewed[0]["expires_at"] > sub["expires_at"]


def test_the_health_panel_shows_evictions_by_cause(gw, page):
    topic = "/powertrain/engine/temperature"
    host = gw.host()
    poll_until(lambda: gw.get(f"/components/{host}/data{topic}").json()["x-medkit"]["status"] == "data",
               15, message="the topic pooled")
    client = gw.rosworker_client()
    try:
        assert client.call("evict", {"topic": topic})["evicted"] is True
    finally:
        client.close()
    provider = gw.get("/health").json()["x-medkit-data-provider"]
    manual = provider["evictions"]["manual"]
    assert manual >= 1 and provider["evictions_total"] >= manual
    tab, _ = page
    tab.goto(gw.url + "/ui/")
    # In words: why topics were let go, how many are read, whether anybody waits ...
    expect(tab.locator("#health li[data-key='dropped']")).to_contain_text(f"{manual} on request (sovd-probe evict)")
    expect(tab.locator("#health li[data-key='topics']")).to_have_text(re.compile(r"^Reading \d+ topics? \(up to 256\)"))
    expect(tab.locator("#health li[data-key='waiting']")).to_have_text(re.compile(r"waiting for a topic's first message"))
    # ... and the gateway's own counters one click away.
    raw = tab.locator("#health details.raw-counters")
    expect(raw.locator("table[data-section='x-medkit-data-provider']")).to_be_hidden()
    raw.locator("summary").click()
    provider = raw.locator("table[data-section='x-medkit-data-provider']")
    expect(provider.locator("tr[data-key='evictions.manual'] td")).to_have_text(str(manual))
    expect(provider.locator("tr[data-key='pool_cap'] td")).to_have_text("256")
    expect(provider.locator("tr[data-key='cold_wait_cap'] td")).to_have_text("4")
    expect(raw).to_have_attribute("open", "")       # it stays open across the next polls


def _prefixed_site(upstream_port: int, listen_port: int) -> str:
    """The gateway mounted under /robot/ (what "relative URLs only" is for)."""
    return f"""
upstream sovd_gateway {{ server 127.0.0.1:{upstream_port} max_fails=0; keepalive 8; }}
server {{
    listen 127.0.0.1:{listen_port};
    location /robot/ {{
        proxy_pass http://sovd_gateway/;
        proxy_http_version 1.1;
        proxy_set_header Connection "";
        proxy_read_timeout 60s;
    }}
}}
"""


def test_the_dashboard_works_under_a_path_prefix_behind_nginx(gw, page, tmp_path_factory):
    from tests.system.test_nginx import Nginx

    tab, watch = page
    none_left(gw, "temp_sensor")
    nginx = Nginx(gw.port, tmp_path_factory.mktemp("nginx-ui"), site=_prefixed_site,
                  health="/robot/api/v1/health")
    try:
        tab.goto(nginx.url + "/robot/")
        assert tab.url == nginx.url + "/robot/ui/"
        sign_in(tab)
        expect(tab.locator("a.topic[data-topic='/powertrain/engine/temperature']").first).to_be_attached()
        tab.evaluate("location.hash = '#/apps/temp_sensor/data/powertrain/engine/temperature'")
        value = leaf(tab, "temperature")
        expect(value).to_have_text(NUMBER)
        expect(value).not_to_have_text(value.text_content(), timeout=2000)   # the stream through nginx
        tab.evaluate("location.hash = '#/'")
        poll_until(lambda: subscriptions(gw, "temp_sensor") == [], 5, message="the subscription deleted")
        outside = [u for u in watch.requests if not u.startswith(nginx.url + "/robot/")]
        assert outside == []
    finally:
        watch.stop()
        tab.goto("about:blank")
        nginx.stop()
        shutil.rmtree(nginx.prefix, ignore_errors=True)


# The Logs panel's live tail of the demo robot's /rosout: severity, node and search filters, one time format,
# and the lines of the entity the page looks at.
def test_the_logs_panel_tails_the_robots_lines_and_filters_them(gw, page):
    tab, _ = page
    tab.goto(gw.url + "/ui/")
    expect(tab.locator("#logs-scope .scope-name")).to_have_text("whole robot")
    lines = tab.locator("#logs-body .log-line")
    expect(lines.first).to_be_visible()
    seen = lines.count()
    poll_until(lambda: lines.count() > seen, 20, message="new log lines on screen without a reload")
    assert tab.locator("#logs-body .log-line[data-severity='debug']").count() > 0  # the brakes' debug lines
    expect(lines.first.locator(".log-time")).to_have_text(re.compile(r"^\d\d:\d\d:\d\d\.\d{3}$"))  # 24-hour, local
    # A node: only its lines are shown (the others are hidden, not asked again).
    expect(tab.locator("#logs-node option[value='chassis.brakes.pressure_sensor']")).to_be_attached()
    tab.select_option("#logs-node", "chassis.brakes.pressure_sensor")
    visible = tab.locator("#logs-body .log-line:visible")
    expect(visible.first).to_be_visible()
    assert set(visible.evaluate_all("els => els.map(e => e.dataset.node)")) == {"chassis.brakes.pressure_sensor"}
    tab.select_option("#logs-node", "")
    # Words of the message.
    tab.fill("#logs-search", "wheel slip")
    expect(visible.first).to_contain_text("wheel slip", timeout=45_000)   # the demo's wheel slips every 30 s
    assert all("wheel slip" in t for t in visible.all_text_contents())
    tab.fill("#logs-search", "")
    tab.select_option("#logs-severity", "error")
    expect(tab.locator("#logs-body .log-line[data-severity='error']").first).to_contain_text("wheel slip")
    for severity in ("debug", "info", "warning"):
        expect(tab.locator(f"#logs-body .log-line[data-severity='{severity}']")).to_have_count(0)
    tab.select_option("#logs-severity", "")
    # Looking at an app: its lines only, until the whole robot is asked for again.
    tab.evaluate("location.hash = '#/apps/temp_sensor/configurations'")
    expect(tab.locator("#logs-scope .scope-name")).to_have_text("temp_sensor")
    expect(tab.locator("#logs-body .log-line").first).to_be_visible()
    poll_until(lambda: set(tab.locator("#logs-body .log-line").evaluate_all("els => els.map(e => e.dataset.node)"))
               == {"powertrain.engine.temp_sensor"}, 10, message="only the engine's lines")
    tab.locator("#logs-scope button").click()
    expect(tab.locator("#logs-scope .scope-name")).to_have_text("whole robot")
    expect(tab.locator("#logs-body .log-line[data-node='chassis.odometry']").first).to_be_attached()


# ---- "notify me when…" (app/ui/js/notify.js): a LeaveRange trigger and its events ----
def test_notify_me_when_a_field_leaves_its_range(gw, page):
    from tests.support.linepub import LinePublisher

    tab, _ = page
    pub = LinePublisher("ui_notify_probe", "/ui_notify/level", "std_msgs/msg/Float64")
    try:
        poll_until(lambda: gw.get("/apps/ui_notify_probe").status_code == 200, 30, message="the probe's app")
        tab.goto(gw.url + "/ui/#/apps/ui_notify_probe/data/ui_notify/level")
        sign_in(tab)
        pub.wait_subscribers(1)    # the page's cyclic subscription
        pub.send({"data": 5.0})
        expect(leaf(tab, "data")).to_have_text(NUMBER)
        form = tab.locator("#item form.notify")
        tab.click("#item button.pick[data-path='data']")   # picking the field fills in its JSON Pointer
        expect(form.locator("input[type=text]")).to_have_value("/data")
        form.locator("input[aria-label='lower bound']").fill("0")
        form.locator("input[aria-label='upper bound']").fill("10")
        form.locator("button[type=submit]").click()
        expect(form).to_have_attribute("data-trigger", re.compile(r"^trig_[0-9a-f]{16}$"))
        trig = form.get_attribute("data-trigger")
        expect(form.locator(".notify-state")).to_have_text("watching")   # the gateway's id is not shown
        expect(form).not_to_contain_text("trig_")
        made = gw.get(f"/apps/ui_notify_probe/triggers/{trig}").json()
        assert made["trigger_condition"] == {"condition_type": "LeaveRange", "lower_bound": 0, "upper_bound": 10}
        pub.wait_subscribers(2)    # the page's cyclic subscription and the trigger's
        for value in (5.0, 7.0, 20.0, 30.0, 3.0, -1.0):
            pub.send({"data": value})
        events = form.locator(".notify-events li")
        expect(events).to_have_count(2)
        expect(events.nth(0)).to_contain_text("left the range: -1")
        expect(events.nth(1)).to_contain_text("left the range: 20")
        expect(events.nth(0).locator("time")).to_have_text(re.compile(r"^\d\d:\d\d:\d\d\.\d{3}$"))
        form.locator("button[type=submit]").click()   # Stop: the trigger is deleted
        poll_until(lambda: gw.get(f"/apps/ui_notify_probe/triggers/{trig}").status_code == 404, 10,
                   message="the trigger deleted")
    finally:
        pub.stop()


# ---- every panel on screen: bounded, within the window, and one screenshot each ----------------------
def test_each_panel_fits_the_window_and_is_screenshot(gw, page, tmp_path):
    """The page fits a 1360×860 window: the logs stay in view below a long value, and the faults list
    scrolls inside its panel.  Each panel is saved as a picture (``SOVD_UI_SHOTS=<dir>`` keeps them) for a
    person to look at."""
    tab, _ = page
    shots = os.environ.get("SOVD_UI_SHOTS") or str(tmp_path)
    os.makedirs(shots, exist_ok=True)
    none_left(gw, "odometry")
    tab.goto(gw.url + "/ui/#/apps/odometry/data/chassis/odom")
    sign_in(tab)
    expect(leaf(tab, "pose.pose.position.x")).to_have_text(NUMBER)
    expect(tab.locator("#health li[data-key='faults']")).to_be_visible()
    expect(tab.locator(".fault[data-code='ODOMETRY_WHEEL_SLIP']")).to_be_visible(timeout=45_000)
    expect(tab.locator("#logs-body .log-line").first).to_be_visible()
    tab.locator(".fault[data-code='ODOMETRY_WHEEL_SLIP'] .fault-head").click()
    expect(tab.locator(".fault[data-code='ODOMETRY_WHEEL_SLIP'] table.frame")).to_be_visible()
    height = VIEWPORT["height"]
    for panel in ("nav.tree-panel", "#item", "#health", "#faults", "#logs"):
        box = tab.locator(panel).bounding_box()
        assert box["y"] >= 0 and box["y"] + box["height"] <= height + 1, (panel, box)
    shots_taken = {"page": tab.screenshot(path=f"{shots}/page.png")}
    for name, selector in (("tree", "nav.tree-panel"), ("item", "#item"), ("health", "#health"),
                           ("faults", "#faults"), ("logs", "#logs")):
        shots_taken[name] = tab.locator(selector).screenshot(path=f"{shots}/{name}.png")
    tab.locator("#health details.raw-counters summary").click()
    shots_taken["health-raw"] = tab.locator("aside.side").screenshot(path=f"{shots}/health-raw.png")
    tab.evaluate("location.hash = '#/apps/calibration/operations'")
    action = tab.locator("form.operation[data-operation='long_calibration']")
    expect(action.locator("ol.op-past")).to_be_attached()
    shots_taken["operations"] = tab.locator("#item").screenshot(path=f"{shots}/operations.png")
    tab.evaluate("location.hash = '#/apps/temp_sensor/configurations'")
    expect(tab.locator("#item form.parameter").first).to_be_visible()
    shots_taken["parameters"] = tab.locator("#item").screenshot(path=f"{shots}/parameters.png")
    for name, png in shots_taken.items():
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 2000, name
