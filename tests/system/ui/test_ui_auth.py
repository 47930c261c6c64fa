"""The dashboard's sign-in in a real browser (chromium, playwright) against a real gateway with
identities and roles (``auth_enabled``) and the demo robot.

The page signs in with OAuth2 client credentials, keeps the tokens in memory only (no storage, no
cookie, no field of the page), shows the role, and offers only what that role may do: a viewer reads
(the value polled, no stream, no publish form), an operator publishes and streams but sets no
parameter, an admin reads the audit trail.  With ``require_auth_for=all`` nothing is shown before the
sign-in, and everything after it (the event streams carry the token over fetch).
"""

from __future__ import annotations

import pytest

from common.harness.gateway import Gateway
from common.harness.procs import poll_until
from tests.support.auth import ENV, SECRETS
from tests.system.ui.test_ui import NUMBER, browser, expect, leaf, page, robot  # noqa: F401 - fixtures

TEMPERATURE = "/ui/#/apps/temp_sensor/data/powertrain/engine/temperature"


# (the legacy api_token too: the test's own health checks use it when every read needs a token)
GATEWAY_ENV = {**ENV, "SOVD_API_TOKEN": "ui-legacy-admin-token-0123"}


def sees_the_robot(gateway: Gateway) -> Gateway:
    poll_until(lambda: gateway.get("/apps/temp_sensor/configurations/publish_rate",
                                   headers=admin_headers(gateway)).status_code == 200, 60, interval=0.2,
               message="the demo robot")
    return gateway


def started(*args: str) -> Gateway:
    """A gateway of the test's own (stopped by the test)."""
    gateway = Gateway("--auth-enabled", *args, env=GATEWAY_ENV)
    try:
        return sees_the_robot(gateway)
    except BaseException:
        gateway.stop()
        raise


def admin_headers(gateway: Gateway) -> dict:
    from tests.support.auth import bearer, grant

    if not hasattr(gateway, "admin"):
        gateway.admin = bearer(grant(gateway, "admin"))
    return gateway.admin


@pytest.fixture(scope="module")
def gw(robot, gateway):  # noqa: F811
    return sees_the_robot(gateway("--auth-enabled", "--allow-publish", "--allow-configurations", env=GATEWAY_ENV))


def sign_in(tab, role: str, secret: str | None = None) -> None:
    form = tab.locator("#signin")
    expect(form).to_be_visible()
    tab.fill("#signin-client", role)
    tab.fill("#signin-secret", secret if secret is not None else SECRETS[role])
    form.get_by_role("button", name="Sign in").click()


def signed_in_as(tab, role: str) -> None:
    expect(tab.locator("#who-role")).to_have_text(role)
    expect(tab.locator("#who-name")).to_have_text(role)
    expect(tab.locator("#signin")).to_be_hidden()


def nothing_kept(tab) -> None:
    """No token or secret outside the page's script memory: storage, cookies, form fields, the URL."""
    kept = tab.evaluate("""() => ({
        storage: [localStorage.length, sessionStorage.length], cookie: document.cookie, url: location.href,
        fields: [...document.querySelectorAll('input')].map((i) => i.value).filter((v) => v.length > 20)})""")
    assert kept["storage"] == [0, 0] and kept["cookie"] == "" and kept["fields"] == [], kept
    assert "token" not in kept["url"] and "secret" not in kept["url"]


def test_sign_in_shows_the_role_and_only_what_it_may_do(gw, page):  # noqa: F811
    tab, watch = page
    watch.allow("POST", 401)   # provoked: a wrong secret
    tab.goto(gw.url + TEMPERATURE)
    # not signed in: the value is read (reads are open), but nothing that writes is offered
    expect(leaf(tab, "temperature")).to_have_text(NUMBER)
    expect(tab.locator("#item .item-controls .badge")).to_have_text("polling")
    expect(tab.locator("form.publish")).to_have_count(0)
    expect(tab.locator("#token")).to_be_hidden()   # no legacy token field: the sign-in instead
    sign_in(tab, "viewer", "a wrong secret")
    expect(tab.locator("#signin-error")).to_have_text("wrong client id or secret")
    expect(tab.locator("#who")).to_be_hidden()

    sign_in(tab, "viewer")
    signed_in_as(tab, "viewer")
    expect(tab.locator("#item .stream-detail")).to_contain_text("a viewer may not make cyclic subscriptions")
    expect(leaf(tab, "temperature")).to_have_text(NUMBER)
    expect(tab.locator("form.publish")).to_have_count(0)
    expect(tab.locator("#audit-link")).to_be_hidden()
    nothing_kept(tab)

    tab.locator("#signout").click()
    expect(tab.locator("#signin")).to_be_visible()
    sign_in(tab, "operator")
    signed_in_as(tab, "operator")
    expect(tab.locator("#item .item-controls .badge")).to_have_text("live")   # a cyclic subscription now
    expect(tab.locator("form.publish")).to_have_count(1)
    expect(leaf(tab, "temperature")).to_have_text(NUMBER)
    tab.goto(gw.url + "/ui/#/apps/temp_sensor/configurations")   # (the page keeps its memory: a hash change)
    rate = tab.locator("form.parameter[data-parameter='publish_rate']")
    expect(rate.locator(".param-value")).to_have_text("10")
    expect(tab.get_by_role("button", name="Set")).to_have_count(0)   # an operator may not configure
    nothing_kept(tab)


def test_an_admin_reads_the_audit_trail(gw, page):  # noqa: F811
    tab, _ = page
    gw.put("/apps/temp_sensor/configurations/publish_rate", json={"data": 10.0}, headers=admin_headers(gw))
    tab.goto(gw.url + "/ui/")
    sign_in(tab, "admin")
    signed_in_as(tab, "admin")
    tab.locator("#audit-link").click()
    expect(tab.locator("#item h2")).to_have_text("Audit trail")
    row = tab.locator("table.audit tbody tr").filter(has_text="/api/v1/apps/temp_sensor/configurations/publish_rate")
    expect(row.first).to_contain_text("admin")
    expect(row.first.locator("td.status")).to_have_text("200")
    expect(tab.locator("table.audit tbody tr").filter(has_text="/api/v1/auth/authorize").first).to_be_attached()


def test_with_require_auth_for_all_the_page_waits_for_the_sign_in(robot, page):  # noqa: F811
    tab, watch = page
    watch.allow("GET", 401)   # the overview before the sign-in
    gateway = started("--require-auth-for", "all")
    try:
        tab.goto(gateway.url + TEMPERATURE)
        expect(tab.locator("#gateway-version")).to_have_text("sign in to see the robot")
        expect(tab.locator(".tree .app")).to_have_count(0)
        sign_in(tab, "operator")
        signed_in_as(tab, "operator")
        expect(tab.locator(".tree .app[data-app='temp_sensor']").first).to_be_attached()
        expect(leaf(tab, "temperature")).to_have_text(NUMBER)   # a stream over fetch, with the token
        expect(tab.locator("#item .item-controls .badge")).to_have_text("live")
        expect(tab.locator("#worker-badge")).to_have_attribute("data-state", "healthy")
        expect(tab.locator("#faults-summary")).to_be_attached()
        nothing_kept(tab)
    finally:
        gateway.stop()
