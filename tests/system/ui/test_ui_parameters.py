"""The dashboard's Parameters panel in a real browser (chromium, playwright) against a real gateway and
the demo robot's engine (demo/tuning.py: publish_rate 0.5–50, sensor_id read-only, filter_window 1–20):
read, edit publish_rate, and the node's reason when an out-of-range filter_window is refused."""

from __future__ import annotations

import pytest

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from tests.system.ui.test_ui import TOKEN, browser, expect, page, robot, sign_in  # noqa: F401 - fixtures

BASE = "/apps/temp_sensor/configurations"


@pytest.fixture(scope="module")
def gw(robot, gateway):  # noqa: F811 - the module's own gateway: configuration writes allowed
    gw = gateway("--allow-configurations", "--api-token", TOKEN)
    poll_until(lambda: gw.get(BASE + "/publish_rate").status_code == 200, 60, interval=0.2,
               message="the demo engine's parameters")
    return gw


def test_parameters_panel_reads_sets_and_shows_the_nodes_refusal(gw, page):  # noqa: F811
    tab, watch = page
    watch.allow("PUT", 400)   # provoked: filter_window 50 is out of the node's range
    tab.goto(gw.url + "/ui/")
    expect(tab.locator("a.params-link[data-app='temp_sensor']").first).to_be_attached()
    tab.goto(gw.url + "/ui/#/apps/temp_sensor/configurations")
    sign_in(tab)

    rate = tab.locator("form.parameter[data-parameter='publish_rate']")
    expect(rate.locator(".param-value")).to_have_text("10")
    expect(rate.locator(".param-type")).to_contain_text("double")
    expect(rate.locator(".param-range")).to_have_text("0.5 – 50")
    window = tab.locator("form.parameter[data-parameter='filter_window']")
    expect(window.locator(".param-range")).to_have_text("1 – 20, step 1")
    sensor = tab.locator("form.parameter[data-parameter='sensor_id']")
    expect(sensor.locator(".param-value")).to_have_text("ecu-1-temp")
    expect(sensor.locator(".param-read-only")).to_be_visible()
    expect(sensor.get_by_role("button", name="Set")).to_have_count(0)   # no editor for a read-only parameter

    rate.get_by_label("publish_rate new value").fill("20.0")
    rate.get_by_role("button", name="Set").click()
    expect(rate.locator(".form-status")).to_have_text("set")
    expect(rate.locator(".param-value")).to_have_text("20")
    assert gw.get(BASE + "/publish_rate").json()["data"] == 20.0   # the node has it

    window.get_by_label("filter_window new value").fill("50")
    window.get_by_role("button", name="Set").click()
    status = window.locator(".form-status")
    expect(status).to_have_attribute("data-refused", "true")
    reason = gw.get(BASE + "/filter_window").json()
    assert reason["data"] == 5   # unchanged
    expect(status).to_contain_text("Refused:")
    expect(status).to_contain_text("filter_window")   # the node's own reason names the parameter
    expect(status).to_contain_text("400")
    expect(window.locator(".param-value")).to_have_text("5")


def test_without_allow_configurations_the_panel_is_read_only(robot, page):  # noqa: F811
    tab, _ = page
    gateway = Gateway("--api-token", TOKEN)
    try:
        poll_until(lambda: gateway.get(BASE + "/publish_rate").status_code == 200, 60, interval=0.2,
                   message="the demo engine's parameters")
        tab.goto(gateway.url + "/ui/#/apps/temp_sensor/configurations")
        rate = tab.locator("form.parameter[data-parameter='publish_rate']")
        expect(rate.locator(".param-range")).to_have_text("0.5 – 50")
        expect(tab.get_by_text("Read-only: the gateway does not allow configuration changes")).to_be_visible()
        expect(tab.get_by_role("button", name="Set")).to_have_count(0)
    finally:
        gateway.stop()
