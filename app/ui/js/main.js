// The dashboard's entry point: the overview (GET /api/v1/), the health panel, the entity tree,
// and the data item view chosen by the location hash (#/apps/<id>/data/<topic>).
//
// One data item view at a time, so the page holds at most one stream.  The view is destroyed
// (its subscription DELETEd) when the hash changes and when the page goes away (pagehide: the
// DELETE is then sent as a keepalive request).  The tree is reloaded by its button, after the ROS
// worker comes back from an outage, and every TREE_RELOAD_MS while the gateway is healthy.

import { describe, get, getToken, setToken } from "./api.js";
import { fill, h } from "./dom.js";
import { HealthPanel } from "./health.js";
import { ItemView } from "./item.js";
import { OperationsView } from "./ops.js"; // operations: services and actions
import { EntityTree } from "./tree.js";
import { FaultsPanel } from "./faults.js"; // faults
import { LogsPanel } from "./logs.js"; // logs: a live tail of /rosout
import { ParametersView } from "./params.js"; // the Parameters panel of an app
import { follow } from "./scope.js"; // the entity whose faults and logs the panels show
import { RobotPicker } from "./fleet.js"; // fleet (issue 34): the robot picker

const TREE_RELOAD_MS = 30000;
const ROUTE = /^#\/(apps|components|functions)\/([A-Za-z0-9_-]+)\/data\/(.+)$/;
const OPS_ROUTE = /^#\/(apps|components|functions)\/([A-Za-z0-9_-]+)\/operations$/; // operations panel

const $ = (id) => document.getElementById(id);
let capabilities = {};
let view = null;
let overviewLoaded = false;

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
    $("gateway-version").textContent = `${overview.version}` +
      (capabilities.publishing ? " · publishing on" : " · read-only");
    $("token").hidden = !capabilities.authentication;
    overviewLoaded = true;
  } catch (error) {
    $("gateway-version").textContent = `overview not loaded: ${describe(error)}`;
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
  if ($("token").value !== getToken()) $("token").value = getToken();
});
setInterval(() => {
  if (health.state === "healthy" && !document.hidden && Date.now() - tree.loadedAt >= TREE_RELOAD_MS) tree.load();
}, 1000);

health.start();
await loadOverview();
// fleet (issue 34): the robot picker, on the fleet gateway and on a robot's page through it (js/fleet.js)
new RobotPicker($("worker-badge").parentElement, $("worker-badge")).start(capabilities);
tree.load();
showRoute();
faults.start(capabilities); // live from the fault stream; Clear only when the gateway clears faults
logs.start();
