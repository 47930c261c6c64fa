"""The dashboard's Faults panel in a real browser (chromium), from a real /diagnostics publisher."""

from __future__ import annotations

import pytest

from bench.diagpub import DiagPub
from tests.support.browser import Watch, launch, require_chromium
from tests.support.gateway import Gateway
from tests.support.procs import poll_until

TOKEN = "ui-faults-token-0123456789"


def expect(*args, **kw):
    from playwright.sync_api import expect as playwright_expect

    return playwright_expect(*args, **kw)


@pytest.fixture(scope="module")
def browser():
    require_chromium()
    from playwright.sync_api import expect as playwright_expect

    playwright_expect.set_options(timeout=20_000)   # a loaded 2-core machine is slow; no timing is asserted
    with launch() as b:
        yield b


def test_a_fault_appears_changes_and_is_cleared_without_a_reload(browser):
    gw = Gateway("--fault-confirm-count", "2", "--fault-heal-count", "1", "--fault-stale-s", "0",
                 "--allow-fault-clear", "--api-token", TOKEN)
    pub = DiagPub("ui_battery", rate=2)
    context = browser.new_context(viewport={"width": 1360, "height": 860})
    tab = context.new_page()
    watch = Watch(tab)
    try:
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
        # The detail is read through the host component, which holds the fault once the gateway's
        # graph knows its node (the status itself may come first).
        poll_until(lambda: gw.get(f"/components/{gw.host()}/faults/UI_BATTERY_BATTERY").status_code == 200, 20,
                   message="the fault in the host component's scope")
        row.locator(".fault-head").click()
        expect(row.locator(".snapshot pre")).to_contain_text('"charge_percent": "12"')
        pub.set([{"name": "ui_battery: Battery", "level": 0, "message": "ok"}])
        expect(row).to_have_attribute("data-status", "HEALED")
        expect(tab.locator("#faults-summary")).to_have_text("0 active, 1 kept")
        # Clear: with the token from the header
        tab.fill("#token", TOKEN)
        row.locator("button", has_text="Clear").click()
        expect(row).to_have_attribute("data-status", "CLEARED")
        poll_until(lambda: gw.get("/faults?status=cleared").json()["items"][0]["status"] == "CLEARED", 10,
                   message="cleared on the gateway")
    finally:
        problems = watch.stop()
        context.close()
        pub.stop()
        gw.stop()
    assert problems == [], "\n".join(problems)
