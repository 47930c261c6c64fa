"""The dashboard's robot picker on the fleet gateway (issue 34), in a real browser (chromium).

The robots are simulated (``common/harness/fleetsim.py``) behind a real router and a real fleet gateway.  The
picker lists them with their link state and latency; picking one opens the dashboard on that robot
through the fleet gateway (``/fleet/<fleet_id>/ui/``, where every read needs the token, so its field
shows at once); "All robots" goes back to the fleet's merged view.
"""

from __future__ import annotations

import re

import pytest

from common.harness.procs import poll_until
from tests.support.browser import Watch, launch, require_chromium
from tests.support.fleet import TOKEN, FleetGateway, Router, SimFleet
from tests.system.fleet.test_fleet_sim import recorded


def expect(*args, **kw):
    from playwright.sync_api import expect as playwright_expect

    return playwright_expect(*args, **kw)


@pytest.fixture(scope="module")
def fleet():
    require_chromium()
    started = []
    try:
        router = Router()
        started.append(router)
        started.append(SimFleet(router, recorded(), 3))
        gw = FleetGateway("--api-token", TOKEN, "--fleet-aggregate", "--fleet-connect", router.endpoint,
                          "--workers", "1")
        started.append(gw)
        poll_until(lambda: len(gw.get("/health").json()["peers"]) == 3, 30, interval=0.2, message="3 robots")
        yield gw
    finally:
        for proc in reversed(started):
            proc.stop()


def test_the_picker_lists_the_robots_and_opens_one_through_the_fleet(fleet):
    from playwright.sync_api import expect as playwright_expect

    playwright_expect.set_options(timeout=20_000)
    with launch() as browser:
        context = browser.new_context(viewport={"width": 1360, "height": 860})
        tab = context.new_page()
        watch = Watch(tab)
        watch.allow("GET", 401)   # reads before the token is given
        watch.allow("GET", 404)   # the simulated robots answer what they recorded, nothing more
        watch.allow("GET", 400)   # streams are not carried through the fleet
        try:
            tab.goto(fleet.url + "/ui/")
            picker = tab.locator("#robot-picker")
            expect(picker.locator("option")).to_have_count(4)
            expect(picker.locator("option").first).to_have_text("All robots (3)")
            expect(picker.locator("option[value='sim_0001']")).to_have_text(re.compile(r"^sim_0001 · online( · \d+ ms)?$"))
            expect(picker).to_have_value("")
            picker.select_option("sim_0001")
            tab.wait_for_url(re.compile(r"/fleet/sim_0001/ui/$"))
            expect(tab.locator("#robot-picker")).to_have_value("sim_0001")
            expect(tab.locator("#token")).to_be_visible()
            # reads go through the fleet to that robot, with the token once it is given
            tab.fill("#token", TOKEN)
            poll_until(lambda: any("/fleet/sim_0001/api/v1/" in url for url in watch.requests), 10,
                       message="a read through the fleet")
            answer = tab.evaluate("""async (token) => {
                const r = await fetch("../api/v1/components", {headers: {Authorization: `Bearer ${token}`}});
                return [r.status, (await r.json()).items.map((c) => c.id)];
            }""", TOKEN)
            assert answer == [200, ["sim_0001_host"]]
            tab.locator("#robot-picker").select_option("")
            tab.wait_for_url(re.compile(r"127\.0\.0\.1:\d+/ui/$"))
            expect(tab.locator("#robot-picker")).to_have_value("")
        finally:
            problems = watch.stop()
            context.close()
    assert problems == [], "\n".join(problems)
