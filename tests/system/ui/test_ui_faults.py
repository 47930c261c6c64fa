"""The dashboard's Faults panel in a real browser (chromium), from real /diagnostics publishers."""

from __future__ import annotations

import shutil
import tempfile

import pytest

from common.harness.diagpub import DiagPub
from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from tests.support.browser import Watch, headless_browser

TOKEN = "ui-faults-token-0123456789"


def expect(*args, **kw):
    from playwright.sync_api import expect as playwright_expect

    return playwright_expect(*args, **kw)


@pytest.fixture(scope="module")
def browser():
    with headless_browser(20_000) as b:
        yield b


def known(gw: Gateway, *apps: str) -> None:
    """Wait until the gateway's graph knows these nodes (apps), so that their first status is theirs:
    a status that comes before its node is known may be put on another /diagnostics publisher."""
    for app in apps:
        poll_until(lambda a=app: gw.get(f"/apps/{a}").status_code == 200, 30, message=f"the app {app}")


def held_by_host(gw: Gateway, code: str) -> None:
    """Wait until the host component holds the fault (once the gateway's graph knows its node: the
    status itself may come first); on a timeout, say which sources the fault has."""
    try:
        poll_until(lambda: gw.get(f"/components/{gw.host()}/faults/{code}").status_code == 200, 20,
                   message=f"{code} in the host component's scope")
    except AssertionError as exc:
        sources = {f["fault_code"]: f["reporting_sources"] for f in gw.get("/faults?status=all").json()["items"]}
        raise AssertionError(f"{exc}; the faults' reporting sources: {sources}") from None


@pytest.fixture
def tab(browser):
    context = browser.new_context(viewport={"width": 1360, "height": 860})
    page = context.new_page()
    watch = Watch(page)
    yield page
    problems = watch.stop()
    context.close()
    assert problems == [], "\n".join(problems)


def test_a_fault_appears_changes_and_is_cleared_without_a_reload(tab):
    gw = Gateway("--fault-confirm-count", "2", "--fault-heal-count", "1", "--fault-stale-s", "0",
                 "--allow-fault-clear", "--api-token", TOKEN)
    pub = DiagPub("ui_battery", rate=2).matched()   # the gateway hears it ...
    try:
        known(gw, "ui_battery")                        # ... and knows its node: its first report names it
        tab.goto(gw.url + "/ui/")
        expect(tab.locator("#faults-summary")).to_have_text("0 active, 0 kept")
        pub.set([{"name": "ui_battery: Battery", "level": 1, "message": "charge low",
                  "values": {"charge_percent": "12"}}])
        row = tab.locator(".fault[data-code='UI_BATTERY_BATTERY']")
        expect(row).to_have_attribute("data-status", "CONFIRMED")
        expect(row.locator(".sev")).to_have_text("WARN")
        expect(row.locator(".sev")).to_have_class("sev sev-WARN")
        expect(row).to_contain_text("charge low")
        expect(row).to_contain_text("×1")
        expect(tab.locator("#faults-summary")).to_have_text("1 active (1 confirmed), 1 kept")
        # The detail is read through the host component, which holds the fault once the gateway's
        # graph knows its node (the status itself may come first).
        held_by_host(gw, "UI_BATTERY_BATTERY")
        row.locator(".fault-head").click()
        # The freeze frame as a table of the status's values, readable in the panel's width.
        expect(row.locator(".snapshot table.frame tr[data-key='charge_percent'] td")).to_have_text("12")
        expect(row.locator(".snapshot table.frame tr[data-key='message'] td")).to_have_text("charge low")
        pub.set([{"name": "ui_battery: Battery", "level": 0, "message": "ok"}])
        expect(row).to_have_attribute("data-status", "HEALED")
        expect(tab.locator("#faults-summary")).to_have_text("0 active, 1 kept")
        # The app's own faults, when the page looks at it: the same fault, cleared through the app.
        tab.evaluate("location.hash = '#/apps/ui_battery/configurations'")
        expect(tab.locator("#faults-scope .scope-name")).to_have_text("ui_battery")
        row = tab.locator(".fault[data-code='UI_BATTERY_BATTERY']")
        expect(row).to_have_attribute("data-status", "HEALED")
        tab.fill("#token", TOKEN)
        row.locator(".fault-head").click()
        row.locator("button.fault-clear").click()
        expect(row).to_have_attribute("data-status", "CLEARED")
        poll_until(lambda: gw.get("/faults?status=cleared").json()["items"][0]["status"] == "CLEARED", 10,
                   message="cleared on the gateway")
    finally:
        pub.stop()
        gw.stop()


def test_clear_is_not_offered_without_fault_clear_and_faults_of_an_earlier_run_are_told(tab):
    """A gateway on a state dir where an earlier run left an active fault of a node that is gone: the
    panel says so and marks the row.  Clearing is off, so no Clear is offered, even for a fault of a
    node that is here (whose detail shows)."""
    state = tempfile.mkdtemp(prefix="sovd-ui-left-")
    gone = here = gw = None
    try:
        gw = Gateway("--fault-confirm-count", "1", "--fault-stale-s", "0", "--state-dir", state)
        gone = DiagPub("ui_gone", rate=2).matched()
        known(gw, "ui_gone")   # its first report names its node
        gone.set([{"name": "ui_gone: motor", "level": 2, "message": "overheated"}])
        try:
            poll_until(lambda: [f["reporting_sources"] for f in gw.get("/faults").json()["items"]] == [["/ui_gone"]],
                       30, message="the fault confirmed, from its node")
        except AssertionError as exc:
            raise AssertionError(f"{exc}; the faults: {gw.get('/faults?status=all').json()['items']}") from None
        gone.set([], publish=False)   # nothing reports from here on: the record is written once
        poll_until(lambda: gw.get("/health").json()["x-medkit-faults"]["store_pending"] == 0, 10, message="written")
        gw.stop()
        gone.stop()
        gw = Gateway("--fault-confirm-count", "1", "--fault-stale-s", "5", "--state-dir", state)
        here = DiagPub("ui_here", rate=2).matched()
        known(gw, "ui_here")
        here.set([{"name": "ui_here: pump", "level": 1, "message": "pressure low", "values": {"bar": "1.2"}}])
        tab.goto(gw.url + "/ui/")
        note = tab.locator("#faults .left-faults")
        expect(note).to_contain_text("1 active fault was left by an earlier run: /ui_gone is not on the ROS graph",
                                     timeout=60_000)
        expect(note.locator("button")).to_have_count(0)   # clearing is off: nothing to press
        row = tab.locator(".fault[data-code='UI_GONE_MOTOR']")
        expect(row).to_have_attribute("data-left", "true")
        expect(row.locator(".left-mark")).to_have_text("left by an earlier run")
        row.locator(".fault-head").click()
        expect(row.locator(".fault-detail")).to_contain_text("its node is not on the ROS graph")
        pump = tab.locator(".fault[data-code='UI_HERE_PUMP']")
        expect(pump).to_have_attribute("data-status", "CONFIRMED")
        assert pump.get_attribute("data-left") is None
        held_by_host(gw, "UI_HERE_PUMP")
        pump.locator(".fault-head").click()
        expect(pump.locator(".snapshot table.frame tr[data-key='bar'] td")).to_have_text("1.2")
        expect(pump.locator(".fault-actions")).to_be_attached()
        expect(pump.locator("button.fault-clear")).to_have_count(0)    # the gateway would refuse it (403)
    finally:
        for pub in (gone, here):
            if pub is not None:
                pub.stop()
        if gw is not None:
            gw.stop()
        shutil.rmtree(state, ignore_errors=True)


def test_a_faults_recording_is_shown_with_its_download_duration_topics_and_size(tab):
    """Issue 32: a confirmed fault's recording in its detail; the link downloads the MCAP file."""
    from tests.support.rospub import publisher, unique_topic

    topic = unique_topic("ui/rec")
    source = publisher("ui_recorded", topic, "std_msgs/msg/Float64", {"data": 1.0}, rate=20, counter="data")
    gw = Gateway("--fault-rosbag-enabled", "--fault-rosbag-topics", topic, "--fault-rosbag-duration-s", "1",
                 "--fault-rosbag-duration-after-s", "0.2")
    pub = DiagPub("ui_pump", rate=5).matched()
    try:
        known(gw, "ui_pump")
        tab.goto(gw.url + "/ui/")
        poll_until(lambda: gw.get("/health").json()["x-medkit-bulk-data"]["rosbag_buffer_messages"] > 10, 20)
        pub.set([{"name": "ui_pump: Pressure", "level": 2, "message": "too low"}])
        held_by_host(gw, "UI_PUMP_PRESSURE")
        recording = poll_until(lambda: gw.get("/apps/ui_pump/bulk-data/rosbags").json()["items"], 20)[0]
        row = tab.locator(".fault[data-code='UI_PUMP_PRESSURE']")
        expect(row).to_have_attribute("data-status", "CONFIRMED")
        row.locator(".fault-head").click()
        shown = row.locator(".snapshot.recording")
        expect(shown.locator(".recording-topics")).to_have_text(topic)
        expect(shown.locator(".recording-duration")).to_have_text(f"{recording['x-medkit']['duration_sec']:.1f} s")
        expect(shown.locator(".recording-size")).to_contain_text("KB" if recording["size"] >= 1024 else "B")
        link = shown.locator("a.recording-download")
        href = link.get_attribute("href")
        assert href.endswith(f"/bulk-data/rosbags/{recording['id']}"), href
        body = tab.request.get(href)
        assert body.status == 200 and body.body()[:8] == b"\x89MCAP0\r\n" and len(body.body()) == recording["size"]
    finally:
        pub.stop()
        gw.stop()
        source.stop()
