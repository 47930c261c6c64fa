"""The dashboard's Operations panel in a real browser (chromium, playwright) against a real gateway and
the demo robot's arm (demo/calibration.py): list, Run a service, Run an action with live feedback, Cancel."""

from __future__ import annotations

import re

import pytest

from common.harness.procs import poll_until
from tests.system.ui.test_ui import TOKEN, browser, expect, page, robot, sign_in  # noqa: F401 - fixtures

VIEWPORT = {"width": 1360, "height": 860}


@pytest.fixture(scope="module")
def gw(robot, gateway):  # noqa: F811 - the module's own gateway: operations allowed
    gw = gateway("--allow-operations", "--api-token", TOKEN)
    poll_until(lambda: len(gw.get("/apps/calibration/operations").json().get("items", [])) == 2, 60,
               interval=0.2, message="the demo arm's operations")
    return gw


def test_operations_panel_runs_a_service_and_an_action_and_cancels_it(gw, page):  # noqa: F811
    tab, _ = page
    tab.goto(gw.url + "/ui/")
    link = tab.locator("a.ops-link[data-app='calibration']").first
    expect(link).to_be_attached()
    tab.goto(gw.url + "/ui/#/apps/calibration/operations")
    sign_in(tab)
    service = tab.locator("form.operation[data-operation='calibrate']")
    service.get_by_role("button", name="Run").click()
    expect(service.locator(".op-output")).to_contain_text("arm calibrated")

    action = tab.locator("form.operation[data-operation='long_calibration']")
    action.locator("textarea").fill('{"order": 40}')
    action.get_by_role("button", name="Run").click()
    status = action.locator(".form-status")
    expect(status).to_have_text("running")
    # The latest feedback on one line, and how far the goal is: its list grows toward the goal's order.
    feedback = action.locator(".op-feedback")
    expect(feedback).to_have_text(re.compile(r'^Latest feedback: \{"sequence":\[0,1,1(,\d+)*\]\}$'))
    expect(action.locator(".op-progress span")).to_have_text(re.compile(r"^ ([1-9]|[1-9]\d) %$"))
    action.get_by_role("button", name="Cancel").click()
    expect(status).to_have_text("canceled")                    # not SOVD's "failed"
    ids = [i["id"] for i in gw.get("/apps/calibration/operations/long_calibration/executions").json()["items"]]
    assert ids, "the goal the page sent is listed"
    # The past executions, newest first, each in an operator's words.
    past = action.locator("ol.op-past li")
    expect(past.first).to_have_attribute("data-id", ids[0])
    expect(past.first).to_have_attribute("data-state", "canceled")
    # A goal that runs to its end: completed, with its result.
    action.locator("textarea").fill('{"order": 2}')
    action.get_by_role("button", name="Run").click()
    expect(status).to_have_text("completed")
    expect(action.locator(".op-output")).to_contain_text('"sequence": [')
    expect(action.locator(".op-progress span")).to_have_text(" 100 %")
    expect(past.first).to_have_attribute("data-state", "completed")
    expect(past.nth(1)).to_have_attribute("data-state", "canceled")


def test_a_body_that_does_not_fit_is_answered_next_to_the_form(gw, page):  # noqa: F811
    tab, watch = page
    watch.allow("POST", 400)   # provoked: the gateway names the field
    tab.goto(gw.url + "/ui/#/apps/calibration/operations")
    sign_in(tab)
    action = tab.locator("form.operation[data-operation='long_calibration']")
    action.locator("textarea").fill('{"order": "many"}')
    action.get_by_role("button", name="Run").click()
    expect(action.locator(".form-status")).to_contain_text("order")
