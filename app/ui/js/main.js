// The dashboard's entry point: the overview (GET /api/v1/), the health panel, the entity tree,
// and the data item view chosen by the location hash (#/apps/<id>/data/<topic>).
//
// One data item view at a time, so the page holds at most one stream.  The view is destroyed
// (its subscription DELETEd) when the hash changes and when the page goes away (pagehide: the
// DELETE is then sent as a keepalive request).  The tree is reloaded by its button, after the ROS
// worker comes back from an outage, and every TREE_RELOAD_MS while the gateway is healthy.

import { ApiError, describe, get, getToken, identitiesOn, may, setIdentities, setReadsNeedToken, setToken, signIn,
  signOut, whoAmI } from "./api.js";
import { AuditView } from "./audit.js"; // the audit trail, for admin (#/audit)
import { fill, h } from "./dom.js";
import { HealthPanel } from "./health.js";
import { ItemView } from "./item.js";
import { OperationsView } from "./ops.js"; // operations: services and actions
import { EntityTree } from "./tree.js";
import { FaultsPanel } from "./faults.js"; // faults
import { LogsPanel } from "./logs.js"; // logs: a live tail of /rosout
import { ParametersView } from "./params.js"; // the Parameters panel of an app
import { follow } from "./scope.js"; // the entity whose faults and logs the panels show
import { RobotPicker, fleetPlace } from "./fleet.js"; // fleet (issue 34): the robot picker

const TREE_RELOAD_MS = 30000;
const ROUTE = /^#\/(apps|components|functions)\/([A-Za-z0-9_-]+)\/data\/(.+)$/;
const OPS_ROUTE = /^#\/(apps|components|functions)\/([A-Za-z0-9_-]+)\/operations$/; // operations panel

const $ = (id) => document.getElementById(id);
let capabilities = {};
let view = null;
let overviewLoaded = false;
let booted = false;

const tree = new EntityTree($("tree"), $("tree-status"), $("search"), $("show-system"));
const health = new HealthPanel($("health-body"), $("worker-badge"));
const faults = new FaultsPanel($("faults-body"), $("faults-scope"), health);
const logs = new LogsPanel({ body: $("logs-body"), severity: $("logs-severity"), node: $("logs-node"),
                             search: $("logs-search"), status: $("logs-status"), scope: $("logs-scope") });
const ENTITY = /^#\/(apps|components|functions)\/([A-Za-z0-9_-]+)(\/|$)/;

async function loadOverview() {
  try {
    const overview = await get("");
    capabilities = overview.capabilities || {};
    // identities and roles (issue 31): a sign-in instead of the legacy token field
    setIdentities(overview.auth && overview.auth.enabled);
    if (overview.auth && overview.auth.require_auth_for === "all") setReadsNeedToken(true);
    $("gateway-version").textContent = `${overview.version}` +
      (capabilities.publishing ? " · publishing on" : " · read-only");
    $("token").hidden = !capabilities.authentication || identitiesOn();
    overviewLoaded = true;
  } catch (error) {
    if (error instanceof ApiError && error.status === 401 && !fleetPlace().robot) {
      // require_auth_for=all: every read wants a token (a robot's page through the fleet wants the fleet's
      // token for every read too: fleet.js's token field, not a sign-in)
      setIdentities(true);
      setReadsNeedToken(true);
      $("gateway-version").textContent = "sign in to see the robot";
    } else {
      $("gateway-version").textContent = `overview not loaded: ${describe(error)}`;
    }
  }
  showWho();
}

// What the page offers: the gateway's switches (capabilities), and with identities what the signed-in
// role may do (GET auth/x-medkit-whoami's "may"); without a sign-in, nothing that writes.
function effective() {
  if (!identitiesOn()) return capabilities;
  return { ...capabilities, authentication: false,   // no token field: the header's sign-in
           publishing: capabilities.publishing && may("publish"),
           operation_execution: capabilities.operation_execution && may("operations"),
           configuration_writes: capabilities.configuration_writes && may("configurations"),
           fault_clear: capabilities.fault_clear && may("fault_clear"),
           triggers: capabilities.triggers && may("triggers"),
           cyclic_subscriptions: capabilities.cyclic_subscriptions && may("cyclic_subscriptions") };
}

// The sign-in form, or who is signed in (client id, role) and Sign out.
function showWho() {
  const who = whoAmI();
  $("signin").hidden = !identitiesOn() || Boolean(who);
  $("who").hidden = !who;
  $("audit-link").hidden = !(who && may("audit"));
  if (who) {
    $("who-name").textContent = who.client_id;
    $("who-role").textContent = who.role;
    $("who-role").dataset.role = who.role;
  }
}

function showRoute() {
  const match = ROUTE.exec(decodeURI(location.hash));
  if (view) view.destroy();
  view = null;
  tree.select(location.hash);
  // The Faults and Logs panels follow the entity the page looks at (scope.js)
  const entity = ENTITY.exec(decodeURI(location.hash));
  follow(entity ? { collection: entity[1], id: entity[2] } : null);
  const container = $("item");
  const capabilities = effective();
  if (location.hash === "#/audit") {   // the audit trail (issue 31): admin's
    view = new AuditView(container);
    view.start();
    return;
  }
  // operations: services and actions (the Operations panel of an app)
  const ops = OPS_ROUTE.exec(decodeURI(location.hash));
  if (ops) {
    view = new OperationsView(container, { collection: ops[1], entityId: ops[2] }, { capabilities });
    view.start();
    return;
  }
  // the Parameters panel of an app (#/apps/<id>/configurations, js/params.js)
  const params = /^#\/(apps|components|functions)\/([A-Za-z0-9_-]+)\/configurations$/.exec(decodeURI(location.hash));
  if (params) {
    view = new ParametersView(container, { collection: params[1], entityId: params[2] }, { capabilities });
    view.start();
    return;
  }
  if (!match) {
    fill(container, h("div", { class: "placeholder" }, h("h2", {}, "Pick a data item"),
      h("p", {}, "Choose a topic in the tree to see its live value, plot its fields and, where the "
        + "gateway allows it, publish to it.")));
    return;
  }
  const [, collection, entityId, topic] = match;
  view = new ItemView(container, { collection, entityId, topic }, { capabilities });
  view.start();
}

window.addEventListener("hashchange", showRoute);
window.addEventListener("pagehide", () => {
  if (view) view.destroy({ unloading: true });
  view = null;
});
window.addEventListener("sovd-health", (event) => {
  const { state, previous } = event.detail;
  if (state === "healthy" && (previous === "unavailable" || previous === "unreachable")) {
    if (!overviewLoaded) loadOverview();
    tree.load();
    if (view && view.failed) showRoute(); // it could not start while the worker was away
  }
});
$("tree-reload").addEventListener("click", () => tree.load());
// The gateway's bearer token, when it wants one (api.js keeps it; a publish form shows the same).
$("token").addEventListener("input", () => setToken($("token").value));
window.addEventListener("sovd-token", () => {
  if (!identitiesOn() && $("token").value !== getToken()) $("token").value = getToken();
});
// Sign in (OAuth2 client credentials): the tokens stay in api.js's memory; the secret is not kept.
$("signin").addEventListener("submit", async (event) => {
  event.preventDefault();
  const secret = $("signin-secret").value;
  $("signin-secret").value = "";
  $("signin-error").textContent = "";
  try {
    await signIn($("signin-client").value.trim(), secret);
  } catch (error) {
    $("signin-error").textContent = error instanceof ApiError && error.status === 401 ? "wrong client id or secret"
      : describe(error);
  }
});
$("signout").addEventListener("click", async () => {
  await signOut();
  if (!overviewLoaded) location.reload();   // every read wanted the token: start again, signed out
});
window.addEventListener("sovd-auth", async () => {
  if (!booted) {
    await boot();
    return;
  }
  showWho();
  faults.capabilities = effective();   // Clear as the role may
  faults.reload();
  showRoute();                         // the view again, with the controls the role may use
});
setInterval(() => {
  if (health.state === "healthy" && !document.hidden && Date.now() - tree.loadedAt >= TREE_RELOAD_MS) tree.load();
}, 1000);

// Start the panels once the overview is read: at once, or after the sign-in when every read wants a token.
async function boot() {
  await loadOverview();
  if ((!overviewLoaded && identitiesOn()) || booted) return;   // waits for the sign-in (sovd-auth)
  booted = true;
  health.start();
  // fleet (issue 34): the robot picker, on the fleet gateway and on a robot's page through it (js/fleet.js)
  new RobotPicker($("worker-badge").parentElement, $("worker-badge")).start(capabilities);
  tree.load();
  showRoute();
  faults.start(effective()); // live from the fault stream; Clear only when the gateway clears faults (and the role may)
  logs.start();
}

await boot();
